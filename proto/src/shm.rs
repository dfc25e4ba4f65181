//! `#[repr(C)]` layouts of what travels through shared memory between actor processes
//! and the learner: transition chunks (actor -> learner) and policy weights with p(c)
//! (learner -> actors).
//!
//! Both are one flat, 8-byte aligned byte buffer (an iceoryx2 sample with a `[u64]` slice
//! payload): a fixed header, then the arrays back to back, each at an offset computed
//! from the header's counts and dims. Nothing is serialised:
//!
//! - the actor writes every step straight into the loaned sample through
//!   [`ShmChunkWriter`] (a [`StepSink`], like [`Chunk`] itself), so the rollout loop is
//!   the only writer and there is no copy before publishing;
//! - the learner reads a received sample with [`read_chunk`], which copies the arrays
//!   once into an owned [`Chunk`] (the learner keeps chunks across the iteration and
//!   hands them to tch, so one copy on this side is accepted);
//! - weights go the other way with [`write_weights`] / [`read_weights`].
//!
//! Alignment: the buffer start must be 8-byte aligned (a `[u64]` payload is); every `f32`
//! array then starts at a multiple of 4, the `bool` arrays (one byte each, 0 or 1) come
//! last. A buffer that is too short, misaligned, or whose header disagrees with its
//! length is refused with a [`ShmError`] naming what is wrong, never read past its end.

use crate::chunk::{Chunk, Step, StepSink};
use crate::config::LatentPrior;
use bytemuck::{Pod, Zeroable};
use thiserror::Error;

/// `b"ESSC"`: first field of a chunk header.
pub const CHUNK_MAGIC: u32 = u32::from_le_bytes(*b"ESSC");
/// `b"ESSW"`: first field of a weights header.
pub const WEIGHTS_MAGIC: u32 = u32::from_le_bytes(*b"ESSW");
/// Version of these layouts; bumped on any change.
pub const LAYOUT_VERSION: u32 = 2;
/// Most MLP layer sizes (input, hidden.., output) a weights header can carry.
pub const MAX_LAYER_SIZES: usize = 8;

/// Errors about a shared-memory buffer.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum ShmError {
    /// The buffer is shorter than its header says it must be.
    #[error("{what} buffer holds {got} bytes, needs {needed}")]
    TooShort {
        /// Chunk or weights.
        what: &'static str,
        /// Bytes needed.
        needed: usize,
        /// Bytes present.
        got: usize,
    },
    /// The buffer does not start at an 8-byte boundary.
    #[error("{what} buffer is not 8-byte aligned")]
    Misaligned {
        /// Chunk or weights.
        what: &'static str,
    },
    /// Wrong magic or layout version.
    #[error(
        "{what} header has magic {magic:#x} / layout version {version}, expected {expected_magic:#x} / {LAYOUT_VERSION}"
    )]
    BadHeader {
        /// Chunk or weights.
        what: &'static str,
        /// Magic found.
        magic: u32,
        /// Expected magic.
        expected_magic: u32,
        /// Layout version found.
        version: u32,
    },
    /// A field's value is out of range.
    #[error("{what} field `{field}` = {value}: {reason}")]
    BadField {
        /// Chunk or weights.
        what: &'static str,
        /// Field name.
        field: &'static str,
        /// Its value.
        value: String,
        /// Why it is refused.
        reason: &'static str,
    },
    /// More steps pushed than the buffer was laid out for.
    #[error("chunk buffer is full: laid out for {capacity} steps")]
    Full {
        /// Steps the buffer holds.
        capacity: usize,
    },
}

/// FNV-1a 64 of a run id: stamped into every chunk so a learner never accepts a chunk of
/// another run.
pub fn run_id_hash(run_id: &str) -> u64 {
    run_id.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

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

const HEADER_BYTES: usize = std::mem::size_of::<ShmChunkHeader>();

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

/// The header `H` at the start of `buf`: aligned, long enough, with `expected_magic` and
/// this [`LAYOUT_VERSION`] (`magic_version` reads those two fields).
fn checked_header<H: bytemuck::Pod>(
    buf: &[u8],
    what: &'static str,
    expected_magic: u32,
    magic_version: impl Fn(&H) -> (u32, u32),
) -> Result<H, ShmError> {
    let bytes = std::mem::size_of::<H>();
    check_aligned(buf, what)?;
    check_len(buf, what, bytes)?;
    let h: H =
        *bytemuck::try_from_bytes(&buf[..bytes]).map_err(|_| ShmError::Misaligned { what })?;
    let (magic, version) = magic_version(&h);
    if magic != expected_magic || version != LAYOUT_VERSION {
        return Err(ShmError::BadHeader {
            what,
            magic,
            expected_magic,
            version,
        });
    }
    Ok(h)
}

/// `buf` holds at least `needed` bytes of a `what`.
fn check_len(buf: &[u8], what: &'static str, needed: usize) -> Result<(), ShmError> {
    if buf.len() < needed {
        return Err(ShmError::TooShort {
            what,
            needed,
            got: buf.len(),
        });
    }
    Ok(())
}

fn check_aligned(buf: &[u8], what: &'static str) -> Result<(), ShmError> {
    if !(buf.as_ptr() as usize).is_multiple_of(8) {
        return Err(ShmError::Misaligned { what });
    }
    Ok(())
}

fn split_f32_mut<'a>(rest: &mut &'a mut [u8], n: usize) -> Result<&'a mut [f32], ShmError> {
    let (head, tail) = std::mem::take(rest).split_at_mut(4 * n);
    *rest = tail;
    bytemuck::try_cast_slice_mut(head).map_err(|_| ShmError::Misaligned { what: "chunk" })
}

fn split_f32<'a>(rest: &mut &'a [u8], n: usize) -> Result<&'a [f32], ShmError> {
    let (head, tail) = rest.split_at(4 * n);
    *rest = tail;
    bytemuck::try_cast_slice(head).map_err(|_| ShmError::Misaligned { what: "chunk" })
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

/// Fixed header of a weights buffer (112 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct ShmWeightsHeader {
    /// [`WEIGHTS_MAGIC`].
    pub magic: u32,
    /// [`LAYOUT_VERSION`].
    pub layout_version: u32,
    /// [`run_id_hash`] of the run.
    pub run_id_hash: u64,
    /// Monotonic policy version.
    pub version: u64,
    /// Number of valid entries in `sizes`.
    pub n_sizes: u32,
    /// Mean-network layer sizes, input first.
    pub sizes: [u32; MAX_LAYER_SIZES],
    /// Observation width.
    pub obs_dim: u32,
    /// Action width.
    pub act_dim: u32,
    /// Number of latent codes.
    pub n_codes: u32,
    /// Latent prior: 0 none, 1 uniform, 2 Gumbel-softmax.
    pub prior: u32,
    /// Gumbel-softmax temperature.
    pub tau: f32,
    /// 1 when eps is fed, else 0.
    pub use_eps: u32,
    /// Reserved, 0.
    pub reserved: [u32; 3],
}

const WHEADER_BYTES: usize = std::mem::size_of::<ShmWeightsHeader>();

/// Owned policy weights and latent spec as they travel (the actor crate turns them into
/// its `PolicyWeights`); also how a checkpoint keeps the weights an overlapped rollout
/// ran under (serde, in its `state.json`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WeightsMsg {
    /// Run id hash.
    pub run_id_hash: u64,
    /// Policy version.
    pub version: u64,
    /// Mean-network layer sizes.
    pub sizes: Vec<usize>,
    /// Flat mean-network parameters.
    pub params: Vec<f32>,
    /// `[act_dim]` log std.
    pub log_std: Vec<f32>,
    /// `[n_codes]` logits of p(c).
    pub prior_logits: Vec<f32>,
    /// `[obs_dim]` observation mean.
    pub obs_mean: Vec<f32>,
    /// `[obs_dim]` observation std.
    pub obs_std: Vec<f32>,
    /// Latent prior.
    pub prior: LatentPrior,
    /// Gumbel-softmax temperature.
    pub tau: f32,
    /// Whether eps is fed.
    pub use_eps: bool,
}

impl WeightsMsg {
    /// Bytes of its buffer, rounded up to 8.
    pub fn bytes(&self) -> usize {
        let floats = self.params.len()
            + self.log_std.len()
            + self.prior_logits.len()
            + self.obs_mean.len()
            + self.obs_std.len();
        (WHEADER_BYTES + 4 * floats).div_ceil(8) * 8
    }
}

fn prior_code(p: LatentPrior) -> u32 {
    match p {
        LatentPrior::None => 0,
        LatentPrior::Uniform => 1,
        LatentPrior::Gumbel => 2,
    }
}

/// Writes `w` into `buf` (8-byte aligned, at least [`WeightsMsg::bytes`] long).
pub fn write_weights(buf: &mut [u8], w: &WeightsMsg) -> Result<(), ShmError> {
    check_aligned(buf, "weights")?;
    check_len(buf, "weights", w.bytes())?;
    if w.sizes.len() > MAX_LAYER_SIZES || w.sizes.len() < 2 {
        return Err(ShmError::BadField {
            what: "weights",
            field: "sizes",
            value: format!("{:?}", w.sizes),
            reason: "needs 2..=8 layer sizes",
        });
    }
    let mut sizes = [0u32; MAX_LAYER_SIZES];
    for (d, &s) in sizes.iter_mut().zip(&w.sizes) {
        *d = u32::try_from(s).map_err(|_| ShmError::BadField {
            what: "weights",
            field: "sizes",
            value: s.to_string(),
            reason: "too large",
        })?;
    }
    let dim = |field, v: usize| {
        u32::try_from(v).map_err(|_| ShmError::BadField {
            what: "weights",
            field,
            value: v.to_string(),
            reason: "too large",
        })
    };
    let h = ShmWeightsHeader {
        magic: WEIGHTS_MAGIC,
        layout_version: LAYOUT_VERSION,
        run_id_hash: w.run_id_hash,
        version: w.version,
        n_sizes: dim("sizes", w.sizes.len())?,
        sizes,
        obs_dim: dim("obs_dim", w.obs_mean.len())?,
        act_dim: dim("act_dim", w.log_std.len())?,
        n_codes: dim("n_codes", w.prior_logits.len())?,
        prior: prior_code(w.prior),
        tau: w.tau,
        use_eps: u32::from(w.use_eps),
        reserved: [0; 3],
    };
    if w.obs_std.len() != w.obs_mean.len() {
        return Err(ShmError::BadField {
            what: "weights",
            field: "obs_std",
            value: w.obs_std.len().to_string(),
            reason: "length differs from obs_mean",
        });
    }
    let (hb, rest) = buf.split_at_mut(WHEADER_BYTES);
    hb.copy_from_slice(bytemuck::bytes_of(&h));
    let mut rest = rest;
    for src in [
        &w.params,
        &w.log_std,
        &w.prior_logits,
        &w.obs_mean,
        &w.obs_std,
    ] {
        split_f32_mut(&mut rest, src.len())
            .map_err(|_| ShmError::Misaligned { what: "weights" })?
            .copy_from_slice(src);
    }
    Ok(())
}

/// Reads a weights buffer (checked) into a [`WeightsMsg`].
pub fn read_weights(buf: &[u8]) -> Result<WeightsMsg, ShmError> {
    let h: ShmWeightsHeader =
        checked_header(buf, "weights", WEIGHTS_MAGIC, |h: &ShmWeightsHeader| {
            (h.magic, h.layout_version)
        })?;
    let bad = |field, value: String, reason| ShmError::BadField {
        what: "weights",
        field,
        value,
        reason,
    };
    let n_sizes = h.n_sizes as usize;
    if !(2..=MAX_LAYER_SIZES).contains(&n_sizes) {
        return Err(bad("n_sizes", n_sizes.to_string(), "must be in 2..=8"));
    }
    let sizes: Vec<usize> = h.sizes[..n_sizes].iter().map(|&s| s as usize).collect();
    if sizes.iter().any(|&s| s == 0 || s > 1 << 16) {
        return Err(bad("sizes", format!("{sizes:?}"), "must be in 1..=65536"));
    }
    let prior = match h.prior {
        0 => LatentPrior::None,
        1 => LatentPrior::Uniform,
        2 => LatentPrior::Gumbel,
        p => return Err(bad("prior", p.to_string(), "must be 0, 1 or 2")),
    };
    for (field, v) in [
        ("obs_dim", h.obs_dim),
        ("act_dim", h.act_dim),
        ("n_codes", h.n_codes),
    ] {
        if v > 1 << 20 {
            return Err(bad(field, v.to_string(), "too large"));
        }
    }
    let n_params: usize = sizes.windows(2).map(|w| w[0] * w[1] + w[1]).sum();
    let (od, ad, k) = (h.obs_dim as usize, h.act_dim as usize, h.n_codes as usize);
    let needed = (WHEADER_BYTES + 4 * (n_params + ad + k + 2 * od)).div_ceil(8) * 8;
    check_len(buf, "weights", needed)?;
    let mut rest = &buf[WHEADER_BYTES..];
    let mut take = |n| {
        split_f32(&mut rest, n)
            .map(<[f32]>::to_vec)
            .map_err(|_| ShmError::Misaligned { what: "weights" })
    };
    Ok(WeightsMsg {
        run_id_hash: h.run_id_hash,
        version: h.version,
        params: take(n_params)?,
        log_std: take(ad)?,
        prior_logits: take(k)?,
        obs_mean: take(od)?,
        obs_std: take(od)?,
        sizes,
        prior,
        tau: h.tau,
        use_eps: h.use_eps != 0,
    })
}

/// `b"ESSE"`: first field of an evaluation-episode header.
pub const EPISODE_MAGIC: u32 = u32::from_le_bytes(*b"ESSE");

/// Fixed header of an evaluation-episode buffer (80 bytes): one deterministic episode
/// with a given one-hot code, actor -> learner on the `chunks` service (told apart from
/// a chunk by its magic).
///
/// Sizing: after the header the buffer holds the env's state after `reset` and after
/// each step (`f64`, `(len + 1) * state_dim`, for the run log and `ess replay`), then
/// the observation after `reset` and `len` steps of `obs`, `act`, `next_obs` and
/// `mode_rewards` (`f32`): `80 + 8 * (len + 1) * state_dim + 4 * (obs_dim + len * (2 *
/// obs_dim + act_dim + n_modes))` bytes ([`ShmEpisodeLayout`]). One episode travels as
/// one sample, so the largest sample is the env's longest episode: a 1000-step Humanoid
/// episode (obs 348, act 17, 3 modes, state of a few hundred values) is about 2.9 MB of
/// `f32` arrays plus 8 bytes per state value and step. An actor's chunk publisher is
/// sized for its rollout share and grows (power of two) when an episode is larger.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Pod, Zeroable)]
pub struct ShmEpisodeHeader {
    /// [`EPISODE_MAGIC`].
    pub magic: u32,
    /// [`LAYOUT_VERSION`].
    pub layout_version: u32,
    /// [`run_id_hash`] of the run.
    pub run_id_hash: u64,
    /// Index of the actor that ran the episode.
    pub actor: u32,
    /// The one-hot code index the policy was given.
    pub code: u32,
    /// Request the episode answers.
    pub request_id: u64,
    /// Version of the policy weights that acted.
    pub policy_version: u64,
    /// Index of the job in the learner's evaluation.
    pub job: u64,
    /// Steps of the episode.
    pub len: u64,
    /// Observation width.
    pub obs_dim: u32,
    /// Action width.
    pub act_dim: u32,
    /// Behaviour modes of the env (width of `mode_rewards`).
    pub n_modes: u32,
    /// `f32::to_bits` of the eps the policy was given.
    pub eps_bits: u32,
    /// Length of one env state vector (`Env::state`).
    pub state_dim: u32,
    /// Zero (keeps the header a multiple of 8 bytes).
    pub reserved: u32,
}

const EHEADER_BYTES: usize = std::mem::size_of::<ShmEpisodeHeader>();

/// Size of an evaluation-episode buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShmEpisodeLayout {
    /// Observation width.
    pub obs_dim: usize,
    /// Action width.
    pub act_dim: usize,
    /// Behaviour modes.
    pub n_modes: usize,
    /// Length of one env state vector.
    pub state_dim: usize,
    /// Steps.
    pub len: usize,
}

impl ShmEpisodeLayout {
    /// Bytes of the whole buffer, header included, rounded up to 8.
    pub fn bytes(&self) -> usize {
        let doubles = (self.len + 1) * self.state_dim;
        let floats = self.obs_dim + self.len * (2 * self.obs_dim + self.act_dim + self.n_modes);
        (EHEADER_BYTES + 8 * doubles + 4 * floats).div_ceil(8) * 8
    }

    /// `u64` words of the whole buffer (the slice length to loan).
    pub fn words(&self) -> usize {
        self.bytes() / 8
    }

    fn of(h: &ShmEpisodeHeader) -> Result<Self, ShmError> {
        let bad = |field, value: u64| ShmError::BadField {
            what: "episode",
            field,
            value: value.to_string(),
            reason: "too large",
        };
        for (field, v) in [
            ("obs_dim", h.obs_dim),
            ("act_dim", h.act_dim),
            ("n_modes", h.n_modes),
            ("state_dim", h.state_dim),
        ] {
            if v > 1 << 20 {
                return Err(bad(field, v.into()));
            }
        }
        if h.len > 1 << 32 {
            return Err(bad("len", h.len));
        }
        Ok(Self {
            obs_dim: h.obs_dim as usize,
            act_dim: h.act_dim as usize,
            n_modes: h.n_modes as usize,
            state_dim: h.state_dim as usize,
            len: h.len as usize,
        })
    }
}

/// The arrays of one evaluation episode, `[len][dim]` each.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EpisodeArrays {
    /// The env's state after `reset` (`[state_dim]`).
    pub start_state: Vec<f64>,
    /// The env's state after each step.
    pub states: Vec<f64>,
    /// Observation after `reset` (`[obs_dim]`).
    pub start_obs: Vec<f32>,
    /// Observations before each step.
    pub obs: Vec<f32>,
    /// Actions.
    pub act: Vec<f32>,
    /// Observations after each step.
    pub next_obs: Vec<f32>,
    /// Evaluation reward of each mode per step.
    pub mode_rewards: Vec<f32>,
}

/// Writes an episode into `buf` (8-byte aligned, at least [`ShmEpisodeLayout::bytes`]
/// of `header`'s dims and length); the arrays' lengths must be `len x` their widths.
pub fn write_episode(
    buf: &mut [u8],
    mut header: ShmEpisodeHeader,
    e: &EpisodeArrays,
) -> Result<(), ShmError> {
    check_aligned(buf, "episode")?;
    let l = ShmEpisodeLayout::of(&header)?;
    check_len(buf, "episode", l.bytes())?;
    let n = l.len;
    for (field, got, want) in [
        ("start_state", e.start_state.len(), l.state_dim),
        ("states", e.states.len(), n * l.state_dim),
        ("start_obs", e.start_obs.len(), l.obs_dim),
        ("obs", e.obs.len(), n * l.obs_dim),
        ("act", e.act.len(), n * l.act_dim),
        ("next_obs", e.next_obs.len(), n * l.obs_dim),
        ("mode_rewards", e.mode_rewards.len(), n * l.n_modes),
    ] {
        if got != want {
            return Err(ShmError::BadField {
                what: "episode",
                field,
                value: got.to_string(),
                reason: "length differs from len x dims",
            });
        }
    }
    header.magic = EPISODE_MAGIC;
    header.layout_version = LAYOUT_VERSION;
    let (hb, mut rest) = buf.split_at_mut(EHEADER_BYTES);
    hb.copy_from_slice(bytemuck::bytes_of(&header));
    for src in [&e.start_state, &e.states] {
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(8 * src.len());
        rest = tail;
        bytemuck::try_cast_slice_mut::<u8, f64>(head)
            .map_err(|_| ShmError::Misaligned { what: "episode" })?
            .copy_from_slice(src);
    }
    for src in [&e.start_obs, &e.obs, &e.act, &e.next_obs, &e.mode_rewards] {
        split_f32_mut(&mut rest, src.len())
            .map_err(|_| ShmError::Misaligned { what: "episode" })?
            .copy_from_slice(src);
    }
    Ok(())
}

/// Reads an episode buffer (checked) into its header and owned arrays.
pub fn read_episode(buf: &[u8]) -> Result<(ShmEpisodeHeader, EpisodeArrays), ShmError> {
    let h: ShmEpisodeHeader =
        checked_header(buf, "episode", EPISODE_MAGIC, |h: &ShmEpisodeHeader| {
            (h.magic, h.layout_version)
        })?;
    let l = ShmEpisodeLayout::of(&h)?;
    check_len(buf, "episode", l.bytes())?;
    let n = l.len;
    let mut rest = &buf[EHEADER_BYTES..];
    let mut take64 = |m: usize| {
        let (head, tail) = rest.split_at(8 * m);
        rest = tail;
        bytemuck::try_cast_slice::<u8, f64>(head)
            .map(<[f64]>::to_vec)
            .map_err(|_| ShmError::Misaligned { what: "episode" })
    };
    let start_state = take64(l.state_dim)?;
    let states = take64(n * l.state_dim)?;
    let mut take = |m| {
        split_f32(&mut rest, m)
            .map(<[f32]>::to_vec)
            .map_err(|_| ShmError::Misaligned { what: "episode" })
    };
    Ok((
        h,
        EpisodeArrays {
            start_state,
            states,
            start_obs: take(l.obs_dim)?,
            obs: take(n * l.obs_dim)?,
            act: take(n * l.act_dim)?,
            next_obs: take(n * l.obs_dim)?,
            mode_rewards: take(n * l.n_modes)?,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// An 8-aligned byte buffer of `bytes` (rounded up to 8).
    fn aligned(bytes: usize) -> Vec<u64> {
        vec![0u64; bytes.div_ceil(8)]
    }

    fn arb_chunk() -> impl Strategy<Value = (Chunk, u64, u32, u64)> {
        (0usize..6, 1usize..4, 0usize..5, 0usize..20).prop_flat_map(|(od, ad, k, n)| {
            let f = |m: usize| proptest::collection::vec(any::<f32>(), m);
            let b = |m: usize| proptest::collection::vec(any::<bool>(), m);
            (
                (f(n * od), f(n * od), f(n * ad), f(n * ad), f(n)),
                (f(n * k), f(n * k), f(n), b(n), b(n), f(n)),
                any::<u64>(),
                any::<u64>(),
                any::<u32>(),
                any::<u64>(),
            )
                .prop_map(
                    move |(
                        (obs, next_obs, pre_tanh, act, logp),
                        (code, gumbel, eps, terminated, truncated, env_reward),
                        version,
                        run,
                        actor,
                        req,
                    )| {
                        (
                            Chunk {
                                policy_version: version,
                                obs_dim: od,
                                act_dim: ad,
                                n_codes: k,
                                obs,
                                next_obs,
                                pre_tanh,
                                act,
                                logp,
                                code,
                                gumbel,
                                eps,
                                terminated,
                                truncated,
                                env_reward,
                            },
                            run,
                            actor,
                            req,
                        )
                    },
                )
        })
    }

    /// Bitwise equality, so NaNs of any payload count as round-tripped.
    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    fn assert_same(a: &Chunk, b: &Chunk) {
        assert_eq!(
            (a.policy_version, a.obs_dim, a.act_dim, a.n_codes),
            (b.policy_version, b.obs_dim, b.act_dim, b.n_codes)
        );
        for (x, y) in [
            (&a.obs, &b.obs),
            (&a.next_obs, &b.next_obs),
            (&a.pre_tanh, &b.pre_tanh),
            (&a.act, &b.act),
            (&a.logp, &b.logp),
            (&a.code, &b.code),
            (&a.gumbel, &b.gumbel),
            (&a.eps, &b.eps),
            (&a.env_reward, &b.env_reward),
        ] {
            assert_eq!(bits(x), bits(y));
        }
        assert_eq!(a.terminated, b.terminated);
        assert_eq!(a.truncated, b.truncated);
    }

    proptest! {
        #[test]
        fn chunk_roundtrip_preserves_every_field((c, run, actor, req) in arb_chunk()) {
            let layout = ShmChunkLayout::new(c.obs_dim, c.act_dim, c.n_codes, c.len());
            let mut words = aligned(layout.bytes());
            let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut words);
            let header = ShmChunkHeader {
                run_id_hash: run,
                actor,
                request_id: req,
                policy_version: c.policy_version,
                len: c.len() as u64,
                obs_dim: c.obs_dim as u32,
                act_dim: c.act_dim as u32,
                n_codes: c.n_codes as u32,
                ..Default::default()
            };
            let mut w = ShmChunkWriter::new(buf, header).unwrap();
            w.write_chunk(&c).unwrap();
            prop_assert!(w.is_complete());
            let (h, back) = read_chunk(bytemuck::cast_slice(&words)).unwrap();
            prop_assert_eq!(h.run_id_hash, run);
            prop_assert_eq!(h.actor, actor);
            prop_assert_eq!(h.request_id, req);
            prop_assert_eq!(h.len, c.len() as u64);
            assert_same(&c, &back);
        }

        #[test]
        fn weights_roundtrip_preserves_every_field(
            sizes in proptest::collection::vec(1usize..6, 2..5),
            k in 0usize..4,
            act in 1usize..3,
            version: u64,
            run: u64,
            tau: f32,
            use_eps: bool,
            prior in 0u32..3,
            seed: u32,
        ) {
            let f = |n: usize, s: u32| (0..n).map(|i| (i as f32) * 0.5 - s as f32).collect::<Vec<f32>>();
            let od = 3;
            let n_params: usize = sizes.windows(2).map(|w| w[0] * w[1] + w[1]).sum();
            let w = WeightsMsg {
                run_id_hash: run,
                version,
                params: f(n_params, seed),
                log_std: f(act, seed ^ 1),
                prior_logits: f(k, seed ^ 2),
                obs_mean: f(od, seed ^ 3),
                obs_std: f(od, seed ^ 4),
                sizes,
                prior: [LatentPrior::None, LatentPrior::Uniform, LatentPrior::Gumbel][prior as usize],
                tau,
                use_eps,
            };
            let mut words = aligned(w.bytes());
            write_weights(bytemuck::cast_slice_mut(&mut words), &w).unwrap();
            let back = read_weights(bytemuck::cast_slice(&words)).unwrap();
            prop_assert_eq!(bits(&[back.tau]), bits(&[w.tau]));
            let (mut a, mut b) = (back.clone(), w.clone());
            a.tau = 0.0;
            b.tau = 0.0;
            prop_assert_eq!(a, b);
        }
    }

    #[test]
    fn short_misaligned_or_foreign_buffers_are_refused_naming_why() {
        let mut words = aligned(256);
        let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut words);
        assert!(matches!(
            read_chunk(buf),
            Err(ShmError::BadHeader { what: "chunk", .. })
        ));
        let header = ShmChunkHeader {
            len: 100,
            obs_dim: 4,
            act_dim: 1,
            n_codes: 2,
            ..Default::default()
        };
        assert!(matches!(
            ShmChunkWriter::new(buf, header),
            Err(ShmError::TooShort { what: "chunk", .. })
        ));
        assert!(matches!(
            ShmChunkWriter::new(&mut buf[1..], header),
            Err(ShmError::Misaligned { what: "chunk" })
        ));
        let header = ShmChunkHeader { len: 1, ..header };
        let mut w = ShmChunkWriter::new(buf, header).unwrap();
        let z = [0.0f32; 4];
        let step = Step {
            obs: &z,
            next_obs: &z,
            pre_tanh: &z[..1],
            act: &z[..1],
            logp: 0.0,
            code: &z[..2],
            gumbel: &z[..2],
            eps: 0.0,
            terminated: false,
            truncated: true,
            env_reward: 0.0,
        };
        let short = Step {
            obs: &z[..3],
            ..step
        };
        assert!(matches!(
            w.try_push(&short),
            Err(ShmError::BadField { field: "obs", .. })
        ));
        w.try_push(&step).unwrap();
        assert_eq!(w.try_push(&step), Err(ShmError::Full { capacity: 1 }));
        // A header claiming more steps than the buffer holds is refused, not over-read.
        let h: &mut ShmChunkHeader = bytemuck::from_bytes_mut(&mut buf[..HEADER_BYTES]);
        h.len = 1_000;
        assert!(matches!(
            read_chunk(buf),
            Err(ShmError::TooShort { what: "chunk", .. })
        ));
    }

    #[test]
    fn episode_roundtrip_preserves_every_field_and_refuses_chunks() {
        let (od, ad, nm, n) = (3, 2, 4, 7);
        let f = |m: usize, s: f32| (0..m).map(|i| i as f32 * 0.25 - s).collect::<Vec<f32>>();
        let sd = 5;
        let e = EpisodeArrays {
            start_state: (0..sd).map(|i| i as f64 * 0.1 + 1e-12).collect(),
            states: (0..n * sd).map(|i| -(i as f64) * 0.3).collect(),
            start_obs: f(od, 0.5),
            obs: f(n * od, 1.0),
            act: f(n * ad, 2.0),
            next_obs: f(n * od, 3.0),
            mode_rewards: f(n * nm, 4.0),
        };
        let h = ShmEpisodeHeader {
            run_id_hash: 9,
            actor: 2,
            code: 3,
            request_id: 5,
            policy_version: 6,
            job: 11,
            len: n as u64,
            obs_dim: od as u32,
            act_dim: ad as u32,
            n_modes: nm as u32,
            eps_bits: 0.5f32.to_bits(),
            state_dim: sd as u32,
            ..Default::default()
        };
        let l = ShmEpisodeLayout {
            obs_dim: od,
            act_dim: ad,
            n_modes: nm,
            state_dim: sd,
            len: n,
        };
        let mut words = aligned(l.bytes());
        let short = l.bytes() - 8;
        assert!(matches!(
            write_episode(&mut bytemuck::cast_slice_mut(&mut words)[..short], h, &e),
            Err(ShmError::TooShort {
                what: "episode",
                ..
            })
        ));
        write_episode(bytemuck::cast_slice_mut(&mut words), h, &e).unwrap();
        let (h2, back) = read_episode(bytemuck::cast_slice(&words)).unwrap();
        assert_eq!(
            (h2.job, h2.code, h2.eps_bits, h2.len),
            (11, 3, h.eps_bits, 7)
        );
        assert_eq!(back, e);
        // A chunk is not an episode, and an episode is not a chunk.
        assert!(matches!(
            read_chunk(bytemuck::cast_slice(&words)),
            Err(ShmError::BadHeader { .. })
        ));
        assert!(matches!(
            read_episode(&bytemuck::cast_slice::<u64, u8>(&words)[..l.bytes() - 8]),
            Err(ShmError::TooShort { .. })
        ));
    }

    #[test]
    fn run_id_hash_differs_between_runs() {
        assert_ne!(run_id_hash("123-a"), run_id_hash("123-b"));
    }
}
