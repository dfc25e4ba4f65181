//! Transition chunks (actor -> learner): [`ShmChunkWriter`] writes a loaned buffer
//! step by step, [`read_chunk`] copies it into an owned [`Chunk`].

use super::{
    CHUNK_MAGIC, LAYOUT_VERSION, ShmError, check_aligned, check_len, checked_header, split_f32,
    split_f32_mut,
};
use crate::chunk::{Chunk, Step, StepSink};
use bytemuck::{Pod, Zeroable};

/// Fixed header of a chunk buffer (64 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Pod, Zeroable)]
pub struct ShmChunkHeader {
    /// [`CHUNK_MAGIC`].
    pub magic: u32,
    /// [`LAYOUT_VERSION`].
    pub layout_version: u32,
    /// [`run_id_hash`] of the run.
    pub run_id_hash: u64,
    /// Index of the actor that produced the chunk.
    pub actor: u32,
    /// Reserved, 0.
    pub reserved: u32,
    /// Request the chunk answers.
    pub request_id: u64,
    /// Version of the policy weights that produced every step.
    pub policy_version: u64,
    /// Steps the buffer is laid out for (and holds once complete).
    pub len: u64,
    /// Observation width.
    pub obs_dim: u32,
    /// Action width.
    pub act_dim: u32,
    /// Number of latent codes.
    pub n_codes: u32,
    /// Reserved, 0.
    pub reserved2: u32,
}

pub(super) const HEADER_BYTES: usize = std::mem::size_of::<ShmChunkHeader>();

/// Byte offsets of a chunk's arrays for its dims and length.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShmChunkLayout {
    obs_dim: usize,
    act_dim: usize,
    n_codes: usize,
    len: usize,
}

impl ShmChunkLayout {
    /// The layout of a chunk of `len` steps.
    pub fn new(obs_dim: usize, act_dim: usize, n_codes: usize, len: usize) -> Self {
        Self {
            obs_dim,
            act_dim,
            n_codes,
            len,
        }
    }

    /// Floats per step: obs, next_obs, pre_tanh, act, logp, code, gumbel, eps, env_reward.
    fn floats_per_step(&self) -> usize {
        2 * self.obs_dim + 2 * self.act_dim + 2 * self.n_codes + 3
    }

    /// Bytes of the whole buffer, header included, rounded up to 8.
    pub fn bytes(&self) -> usize {
        let raw = HEADER_BYTES + self.len * (4 * self.floats_per_step() + 2);
        raw.div_ceil(8) * 8
    }

    /// `u64` words of the whole buffer (the slice length to loan).
    pub fn words(&self) -> usize {
        self.bytes() / 8
    }
}

/// The array regions of a chunk buffer, in layout order.
struct Regions<F, B> {
    obs: F,
    next_obs: F,
    pre_tanh: F,
    act: F,
    logp: F,
    code: F,
    gumbel: F,
    eps: F,
    env_reward: F,
    terminated: B,
    truncated: B,
}

fn region_lens(l: &ShmChunkLayout) -> [usize; 9] {
    let n = l.len;
    [
        n * l.obs_dim,
        n * l.obs_dim,
        n * l.act_dim,
        n * l.act_dim,
        n,
        n * l.n_codes,
        n * l.n_codes,
        n,
        n,
    ]
}

/// Writes the steps of one chunk straight into a shared-memory buffer.
pub struct ShmChunkWriter<'a> {
    header: &'a mut ShmChunkHeader,
    layout: ShmChunkLayout,
    arrays: Regions<&'a mut [f32], &'a mut [u8]>,
    written: usize,
}

impl<'a> ShmChunkWriter<'a> {
    /// Lays out `buf` (8-byte aligned, at least [`ShmChunkLayout::bytes`] long) for
    /// `header.len` steps of `header`'s dims and writes the header. Steps pushed later
    /// fill the arrays in order.
    pub fn new(buf: &'a mut [u8], mut header: ShmChunkHeader) -> Result<Self, ShmError> {
        check_aligned(buf, "chunk")?;
        let layout = layout_of(&header)?;
        check_len(buf, "chunk", layout.bytes())?;
        header.magic = CHUNK_MAGIC;
        header.layout_version = LAYOUT_VERSION;
        let (hb, mut rest) = buf.split_at_mut(HEADER_BYTES);
        let h: &mut ShmChunkHeader =
            bytemuck::try_from_bytes_mut(hb).map_err(|_| ShmError::Misaligned { what: "chunk" })?;
        *h = header;
        let [
            obs,
            next_obs,
            pre_tanh,
            act,
            logp,
            code,
            gumbel,
            eps,
            env_reward,
        ] = region_lens(&layout);
        let obs = split_f32_mut(&mut rest, obs)?;
        let next_obs = split_f32_mut(&mut rest, next_obs)?;
        let pre_tanh = split_f32_mut(&mut rest, pre_tanh)?;
        let act = split_f32_mut(&mut rest, act)?;
        let logp = split_f32_mut(&mut rest, logp)?;
        let code = split_f32_mut(&mut rest, code)?;
        let gumbel = split_f32_mut(&mut rest, gumbel)?;
        let eps = split_f32_mut(&mut rest, eps)?;
        let env_reward = split_f32_mut(&mut rest, env_reward)?;
        let (terminated, rest) = rest.split_at_mut(layout.len);
        let (truncated, _) = rest.split_at_mut(layout.len);
        Ok(Self {
            header: h,
            layout,
            arrays: Regions {
                obs,
                next_obs,
                pre_tanh,
                act,
                logp,
                code,
                gumbel,
                eps,
                env_reward,
                terminated,
                truncated,
            },
            written: 0,
        })
    }

    /// Steps written so far.
    pub fn written(&self) -> usize {
        self.written
    }

    /// True once every step the buffer was laid out for is written.
    pub fn is_complete(&self) -> bool {
        self.written == self.layout.len
    }

    /// The header as written.
    pub fn header(&self) -> &ShmChunkHeader {
        self.header
    }

    /// Copies a whole [`Chunk`] (same dims) in; for tests and benchmarks, the actor
    /// writes step by step through [`StepSink`].
    pub fn write_chunk(&mut self, c: &Chunk) -> Result<(), ShmError> {
        let (od, ad, k) = (c.obs_dim, c.act_dim, c.n_codes);
        let n = c.len();
        for (field, got, want) in [
            ("obs", c.obs.len(), n * od),
            ("next_obs", c.next_obs.len(), n * od),
            ("pre_tanh", c.pre_tanh.len(), n * ad),
            ("act", c.act.len(), n * ad),
            ("code", c.code.len(), n * k),
            ("gumbel", c.gumbel.len(), n * k),
            ("eps", c.eps.len(), n),
            ("terminated", c.terminated.len(), n),
            ("truncated", c.truncated.len(), n),
            ("env_reward", c.env_reward.len(), n),
        ] {
            if got != want {
                return Err(ShmError::BadField {
                    what: "chunk",
                    field,
                    value: got.to_string(),
                    reason: "length differs from len x dims",
                });
            }
        }
        for t in 0..c.len() {
            self.try_push(&Step {
                obs: &c.obs[t * od..(t + 1) * od],
                next_obs: &c.next_obs[t * od..(t + 1) * od],
                pre_tanh: &c.pre_tanh[t * ad..(t + 1) * ad],
                act: &c.act[t * ad..(t + 1) * ad],
                logp: c.logp[t],
                code: &c.code[t * k..(t + 1) * k],
                gumbel: &c.gumbel[t * k..(t + 1) * k],
                eps: c.eps[t],
                terminated: c.terminated[t],
                truncated: c.truncated[t],
                env_reward: c.env_reward[t],
            })?;
        }
        Ok(())
    }

    /// Writes one step; [`ShmError::Full`] once the buffer holds `len` steps.
    pub fn try_push(&mut self, s: &Step<'_>) -> Result<(), ShmError> {
        let t = self.written;
        let l = &self.layout;
        if t >= l.len {
            return Err(ShmError::Full { capacity: l.len });
        }
        let (od, ad, k) = (l.obs_dim, l.act_dim, l.n_codes);
        for (field, got, want) in [
            ("obs", s.obs.len(), od),
            ("next_obs", s.next_obs.len(), od),
            ("pre_tanh", s.pre_tanh.len(), ad),
            ("act", s.act.len(), ad),
            ("code", s.code.len(), k),
            ("gumbel", s.gumbel.len(), k),
        ] {
            if got != want {
                return Err(ShmError::BadField {
                    what: "chunk step",
                    field,
                    value: got.to_string(),
                    reason: "length differs from the chunk's dims",
                });
            }
        }
        let a = &mut self.arrays;
        a.obs[t * od..(t + 1) * od].copy_from_slice(s.obs);
        a.next_obs[t * od..(t + 1) * od].copy_from_slice(s.next_obs);
        a.pre_tanh[t * ad..(t + 1) * ad].copy_from_slice(s.pre_tanh);
        a.act[t * ad..(t + 1) * ad].copy_from_slice(s.act);
        a.logp[t] = s.logp;
        a.code[t * k..(t + 1) * k].copy_from_slice(s.code);
        a.gumbel[t * k..(t + 1) * k].copy_from_slice(s.gumbel);
        a.eps[t] = s.eps;
        a.env_reward[t] = s.env_reward;
        a.terminated[t] = u8::from(s.terminated);
        a.truncated[t] = u8::from(s.truncated);
        self.written += 1;
        Ok(())
    }
}

impl StepSink for ShmChunkWriter<'_> {
    type Error = ShmError;
    fn push(&mut self, s: &Step<'_>) -> Result<(), ShmError> {
        self.try_push(s)
    }
}

fn layout_of(h: &ShmChunkHeader) -> Result<ShmChunkLayout, ShmError> {
    let bad = |field, value: u64| ShmError::BadField {
        what: "chunk",
        field,
        value: value.to_string(),
        reason: "too large",
    };
    // Bounds that keep every size computation far from overflow.
    if h.obs_dim > 1 << 20 {
        return Err(bad("obs_dim", h.obs_dim.into()));
    }
    if h.act_dim > 1 << 20 {
        return Err(bad("act_dim", h.act_dim.into()));
    }
    if h.n_codes > 1 << 20 {
        return Err(bad("n_codes", h.n_codes.into()));
    }
    if h.len > 1 << 32 {
        return Err(bad("len", h.len));
    }
    Ok(ShmChunkLayout::new(
        h.obs_dim as usize,
        h.act_dim as usize,
        h.n_codes as usize,
        h.len as usize,
    ))
}

/// Reads a chunk buffer's header, checked (magic, layout version, length).
pub fn read_chunk_header(buf: &[u8]) -> Result<ShmChunkHeader, ShmError> {
    let h: ShmChunkHeader = checked_header(buf, "chunk", CHUNK_MAGIC, |h: &ShmChunkHeader| {
        (h.magic, h.layout_version)
    })?;
    let needed = layout_of(&h)?.bytes();
    check_len(buf, "chunk", needed)?;
    Ok(h)
}

/// Copies a chunk buffer into an owned [`Chunk`] (the one copy on the learner's side).
pub fn read_chunk(buf: &[u8]) -> Result<(ShmChunkHeader, Chunk), ShmError> {
    let h = read_chunk_header(buf)?;
    let layout = layout_of(&h)?;
    let mut rest = &buf[HEADER_BYTES..];
    let [
        obs,
        next_obs,
        pre_tanh,
        act,
        logp,
        code,
        gumbel,
        eps,
        env_reward,
    ] = region_lens(&layout);
    let r = Regions {
        obs: split_f32(&mut rest, obs)?,
        next_obs: split_f32(&mut rest, next_obs)?,
        pre_tanh: split_f32(&mut rest, pre_tanh)?,
        act: split_f32(&mut rest, act)?,
        logp: split_f32(&mut rest, logp)?,
        code: split_f32(&mut rest, code)?,
        gumbel: split_f32(&mut rest, gumbel)?,
        eps: split_f32(&mut rest, eps)?,
        env_reward: split_f32(&mut rest, env_reward)?,
        terminated: &rest[..layout.len],
        truncated: &rest[layout.len..2 * layout.len],
    };
    let chunk = Chunk {
        policy_version: h.policy_version,
        obs_dim: layout.obs_dim,
        act_dim: layout.act_dim,
        n_codes: layout.n_codes,
        obs: r.obs.to_vec(),
        next_obs: r.next_obs.to_vec(),
        pre_tanh: r.pre_tanh.to_vec(),
        act: r.act.to_vec(),
        logp: r.logp.to_vec(),
        code: r.code.to_vec(),
        gumbel: r.gumbel.to_vec(),
        eps: r.eps.to_vec(),
        terminated: r.terminated.iter().map(|&b| b != 0).collect(),
        truncated: r.truncated.iter().map(|&b| b != 0).collect(),
        env_reward: r.env_reward.to_vec(),
    };
    Ok((h, chunk))
}
