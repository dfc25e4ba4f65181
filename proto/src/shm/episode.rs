//! Deterministic evaluation episodes (actor -> learner): [`write_episode`] /
//! [`read_episode`].

use super::{
    LAYOUT_VERSION, ShmError, check_aligned, check_len, checked_header, split_f32, split_f32_mut,
};
use bytemuck::{Pod, Zeroable};

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
