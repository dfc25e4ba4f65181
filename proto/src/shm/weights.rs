//! Policy weights and p(c) (learner -> actors): [`write_weights`] / [`read_weights`].

use super::{
    LAYOUT_VERSION, MAX_LAYER_SIZES, ShmError, WEIGHTS_MAGIC, check_aligned, check_len,
    checked_header, split_f32, split_f32_mut,
};
use crate::config::LatentPrior;
use bytemuck::{Pod, Zeroable};

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
