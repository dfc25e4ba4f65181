//! The acting policy: tanh-squashed Gaussian over `[obs, eps, c]`, and latent sampling.
//!
//! - Input layout (fixed for every method): normalised observation, then eps (1 float,
//!   0 when the method does not use it), then the K floats of `c` (zeros for GAIL).
//! - `c` is drawn once per episode: one-hot from a uniform categorical, or the soft
//!   Gumbel-softmax sample of Eq. 7, `c_i = softmax((log p_i + g_i) / tau)`, whose noise
//!   `g` travels with the transitions so the learner can differentiate through `c`.
//! - Acting samples `u ~ N(mean, exp(log_std))` and sends `a = tanh(u)`; the chunk keeps
//!   `u` and its Gaussian log-density (the tanh Jacobian cancels in PPO's ratio).

use ess_proto::Mlp;
use ess_proto::config::LatentPrior;
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

/// Versioned weights the learner publishes for the actors.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyWeights {
    /// Monotonic version; every transition records the version that produced it.
    pub version: u64,
    /// Mean network: `[obs_dim + 1 + n_codes] -> act_dim`.
    pub mean: Mlp,
    /// State-independent log standard deviation, `[act_dim]`.
    pub log_std: Vec<f32>,
    /// Logits of p(c), `[n_codes]` (unnormalised).
    pub prior_logits: Vec<f32>,
    /// Observation normalisation: `(obs - obs_mean) / obs_std`, `[obs_dim]` each.
    pub obs_mean: Vec<f32>,
    /// See `obs_mean`.
    pub obs_std: Vec<f32>,
}

/// How latents are drawn for one method.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatentSpec {
    /// Prior of `c`.
    pub prior: LatentPrior,
    /// Number of codes K.
    pub n_codes: usize,
    /// Gumbel-softmax temperature.
    pub tau: f32,
    /// Whether eps ~ U(-1, 1) is fed (else 0).
    pub use_eps: bool,
}

impl LatentSpec {
    /// Draws `(code, gumbel)` for a new episode into the two `[n_codes]` buffers.
    pub fn sample_code<R: Rng>(
        &self,
        prior_logits: &[f32],
        rng: &mut R,
        code: &mut [f32],
        gumbel: &mut [f32],
    ) {
        code.fill(0.0);
        gumbel.fill(0.0);
        match self.prior {
            LatentPrior::None => {}
            LatentPrior::Uniform => {
                let k = rng.random_range(0..self.n_codes);
                code[k] = 1.0;
            }
            LatentPrior::Gumbel => {
                for g in gumbel.iter_mut() {
                    // Gumbel(0, 1) = -ln(-ln U), U in (0, 1).
                    let u: f32 = rng.random_range(f32::EPSILON..1.0);
                    *g = -(-u.ln()).ln();
                }
                gumbel_softmax(prior_logits, gumbel, self.tau, code);
            }
        }
    }

    /// Draws eps for a new episode.
    pub fn sample_eps<R: Rng>(&self, rng: &mut R) -> f32 {
        if self.use_eps {
            rng.random_range(-1.0..1.0)
        } else {
            0.0
        }
    }
}

/// `out = softmax((log_softmax(logits) + g) / tau)` (Eq. 7).
pub fn gumbel_softmax(logits: &[f32], g: &[f32], tau: f32, out: &mut [f32]) {
    let lmax = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let lse = lmax + logits.iter().map(|l| (l - lmax).exp()).sum::<f32>().ln();
    for ((o, l), gi) in out.iter_mut().zip(logits).zip(g) {
        *o = (l - lse + gi) / tau;
    }
    softmax_in_place(out);
}

/// Numerically stable softmax.
pub fn softmax_in_place(x: &mut [f32]) {
    let m = x.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let mut s = 0.0;
    for v in x.iter_mut() {
        *v = (*v - m).exp();
        s += *v;
    }
    for v in x.iter_mut() {
        *v /= s;
    }
}

/// Reusable buffers for acting with one policy.
#[derive(Debug, Clone)]
pub struct Actor {
    input: Vec<f32>,
    mean: Vec<f32>,
    scratch: Vec<f32>,
}

const LN_SQRT_2PI: f32 = 0.918_938_5;

impl Actor {
    /// Buffers sized for `w`.
    pub fn new(w: &PolicyWeights) -> Self {
        Self {
            input: vec![0.0; w.mean.layout().input()],
            mean: vec![0.0; w.mean.layout().output()],
            scratch: vec![0.0; w.mean.scratch_len()],
        }
    }

    /// Writes the policy input `[norm(obs), eps, c]` and runs the mean network.
    fn mean(&mut self, w: &PolicyWeights, obs: &[f32], eps: f32, code: &[f32]) -> &[f32] {
        let d = obs.len();
        for (((x, o), m), s) in self
            .input
            .iter_mut()
            .zip(obs)
            .zip(&w.obs_mean)
            .zip(&w.obs_std)
        {
            *x = (o - m) / s;
        }
        self.input[d] = eps;
        self.input[d + 1..].copy_from_slice(code);
        w.mean
            .forward(&self.input, &mut self.mean, &mut self.scratch);
        &self.mean
    }

    /// Samples an action: writes `u` and `tanh(u)`, returns the Gaussian log-density of `u`.
    #[allow(clippy::too_many_arguments)]
    pub fn sample<R: Rng>(
        &mut self,
        w: &PolicyWeights,
        obs: &[f32],
        eps: f32,
        code: &[f32],
        rng: &mut R,
        pre_tanh: &mut [f32],
        act: &mut [f32],
    ) -> f32 {
        self.mean(w, obs, eps, code);
        let mut logp = 0.0;
        for i in 0..pre_tanh.len() {
            let n: f32 = StandardNormal.sample(rng);
            let std = w.log_std[i].exp();
            let u = self.mean[i] + std * n;
            pre_tanh[i] = u;
            act[i] = u.tanh();
            logp += -0.5 * n * n - w.log_std[i] - LN_SQRT_2PI;
        }
        logp
    }

    /// Deterministic action `tanh(mean)`.
    pub fn act_deterministic(
        &mut self,
        w: &PolicyWeights,
        obs: &[f32],
        eps: f32,
        code: &[f32],
        act: &mut [f32],
    ) {
        self.mean(w, obs, eps, code);
        for (a, m) in act.iter_mut().zip(&self.mean) {
            *a = m.tanh();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn gumbel_softmax_with_zero_noise_and_unit_tau_is_the_prior() {
        let logits = [0.0f32, 1.0, 2.0];
        let mut out = [0.0; 3];
        gumbel_softmax(&logits, &[0.0; 3], 1.0, &mut out);
        let z: f32 = logits.iter().map(|l| l.exp()).sum();
        for (o, l) in out.iter().zip(logits) {
            assert!((o - l.exp() / z).abs() < 1e-6);
        }
    }

    #[test]
    fn gumbel_codes_follow_the_prior_frequencies() {
        let spec = LatentSpec {
            prior: LatentPrior::Gumbel,
            n_codes: 3,
            tau: 0.1,
            use_eps: true,
        };
        let p = [0.6f32, 0.3, 0.1];
        let logits: Vec<f32> = p.iter().map(|x| x.ln()).collect();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (mut c, mut g) = ([0.0; 3], [0.0; 3]);
        let mut counts = [0usize; 3];
        let n = 20_000;
        for _ in 0..n {
            spec.sample_code(&logits, &mut rng, &mut c, &mut g);
            let k = (0..3).max_by(|&a, &b| c[a].total_cmp(&c[b])).unwrap();
            counts[k] += 1;
            assert!((c.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
        for k in 0..3 {
            let f = counts[k] as f32 / n as f32;
            assert!((f - p[k]).abs() < 0.015, "code {k}: {f} vs {}", p[k]);
        }
    }

    #[test]
    fn uniform_codes_are_one_hot_and_none_codes_are_zero() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let (mut c, mut g) = ([0.0; 4], [0.0; 4]);
        let mut spec = LatentSpec {
            prior: LatentPrior::Uniform,
            n_codes: 4,
            tau: 0.1,
            use_eps: false,
        };
        spec.sample_code(&[0.0; 4], &mut rng, &mut c, &mut g);
        assert_eq!(c.iter().filter(|&&x| x == 1.0).count(), 1);
        assert_eq!(c.iter().sum::<f32>(), 1.0);
        assert_eq!(spec.sample_eps(&mut rng), 0.0);
        spec.prior = LatentPrior::None;
        spec.sample_code(&[0.0; 4], &mut rng, &mut c, &mut g);
        assert_eq!(c, [0.0; 4]);
    }
}
