//! PPO with GAE(lambda) (Sec. 3.3: "pi_theta is optimized using PPO, with advantages
//! computed using GAE(lambda), and the value function is updated using TD(lambda)").
//!
//! The p(c) logits are updated in the same step: with the Gumbel prior, each
//! transition's code is recomputed from its stored Gumbel noise,
//! `c = softmax((log p(c) + g) / tau)` (Eq. 7), so the clipped surrogate's gradient
//! reaches the logits through `c` (Sec. 3.2, "passing the gradient back to the latent
//! skill distribution").

use crate::train::nets::{Mlp, Policy, tensor_2d};
use crate::train::optim::Adam;
use ess_proto::Chunk;
use ess_proto::config::{LatentPrior, PpoConfig};
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use tch::{Kind, Tensor, nn, nn::Module};

/// Generalised advantage estimation over one actor's consecutive steps.
///
/// `values[t] = V(s_t)`, `next_values[t] = V(s_{t+1})`. A `terminated` step has no
/// bootstrap; a `cut` step (time limit, or the end of the chunk) bootstraps from
/// `next_values[t]` and stops the recursion. Returns `(advantages, returns)`.
pub fn gae(
    rewards: &[f32],
    values: &[f32],
    next_values: &[f32],
    terminated: &[bool],
    cut: &[bool],
    gamma: f32,
    lambda: f32,
) -> (Vec<f32>, Vec<f32>) {
    let n = rewards.len();
    let mut adv = vec![0.0; n];
    let mut next_adv = 0.0;
    for t in (0..n).rev() {
        let boot = if terminated[t] { 0.0 } else { next_values[t] };
        let delta = rewards[t] + gamma * boot - values[t];
        let carry = if terminated[t] || cut[t] {
            0.0
        } else {
            next_adv
        };
        adv[t] = delta + gamma * lambda * carry;
        next_adv = adv[t];
    }
    let ret = adv.iter().zip(values).map(|(a, v)| a + v).collect();
    (adv, ret)
}

/// Scales rewards by the running standard deviation of the discounted return, per
/// actor stream (each stream's return carries across iterations until its episode
/// ends). Rewards are scaled, never shifted, so the sign of every term is kept.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct RewardScaler {
    /// Running discounted return of each stream.
    ret: Vec<f64>,
    count: f64,
    mean: f64,
    m2: f64,
}

impl RewardScaler {
    /// Updates the statistics with one stream's consecutive `rewards` (an episode
    /// ends where `done`); divide rewards by [`RewardScaler::std`] afterwards.
    pub fn observe(&mut self, stream: usize, rewards: &[f32], done: &[bool], gamma: f64) {
        if self.ret.len() <= stream {
            self.ret.resize(stream + 1, 0.0);
        }
        let mut g = self.ret[stream];
        for (&r, &d) in rewards.iter().zip(done) {
            g = g * gamma + r as f64;
            self.count += 1.0;
            let delta = g - self.mean;
            self.mean += delta / self.count;
            self.m2 += delta * (g - self.mean);
            if d {
                g = 0.0;
            }
        }
        self.ret[stream] = g;
    }

    /// Observes `rewards` (all `chunks` concatenated, one stream per chunk index) and
    /// returns them divided by the updated return standard deviation.
    pub fn scale_chunks(&mut self, chunks: &[Chunk], rewards: &[f32], gamma: f64) -> Vec<f32> {
        let mut off = 0;
        for (i, c) in chunks.iter().enumerate() {
            let done: Vec<bool> = c
                .terminated
                .iter()
                .zip(&c.truncated)
                .map(|(a, b)| *a || *b)
                .collect();
            self.observe(i, &rewards[off..off + c.len()], &done, gamma);
            off += c.len();
        }
        let s = self.std() as f32;
        rewards.iter().map(|r| r / s).collect()
    }

    /// Standard deviation of the discounted return seen so far (1 before any data).
    pub fn std(&self) -> f64 {
        if self.count < 2.0 {
            1.0
        } else {
            (self.m2 / self.count).sqrt().max(1e-4)
        }
    }
}

/// Advantages and returns of one rollout as both trainers compute them: `rewards`
/// scaled by `scaler` when `cfg.normalize_rewards`, then [`chunks_gae`] with
/// `cfg.gamma` and `cfg.gae_lambda`.
pub fn rollout_gae(
    cfg: &ess_proto::config::PpoConfig,
    scaler: &mut RewardScaler,
    chunks: &[Chunk],
    rewards: &[f32],
    values: &[f32],
    next_values: &[f32],
) -> (Vec<f32>, Vec<f32>) {
    let scaled;
    let rewards = if cfg.normalize_rewards {
        scaled = scaler.scale_chunks(chunks, rewards, cfg.gamma);
        &scaled[..]
    } else {
        rewards
    };
    chunks_gae(
        chunks,
        rewards,
        values,
        next_values,
        cfg.gamma,
        cfg.gae_lambda,
    )
}

/// [`gae`] over each chunk's steps of the concatenated `rewards` / `values` /
/// `next_values` (a chunk's last step is cut: it bootstraps). Returns the
/// concatenated `(advantages, returns)`.
pub fn chunks_gae(
    chunks: &[Chunk],
    rewards: &[f32],
    values: &[f32],
    next_values: &[f32],
    gamma: f64,
    lambda: f64,
) -> (Vec<f32>, Vec<f32>) {
    let mut adv = Vec::with_capacity(rewards.len());
    let mut ret = Vec::with_capacity(rewards.len());
    let mut off = 0;
    for c in chunks {
        let r = off..off + c.len();
        let mut cut = c.truncated.clone();
        if let Some(l) = cut.last_mut() {
            *l = true;
        }
        let (a, rt) = gae(
            &rewards[r.clone()],
            &values[r.clone()],
            &next_values[r],
            &c.terminated,
            &cut,
            gamma as f32,
            lambda as f32,
        );
        adv.extend(a);
        ret.extend(rt);
        off += c.len();
    }
    (adv, ret)
}

/// One iteration's on-policy batch, already normalised and flattened.
pub struct PpoBatch {
    /// `[n, obs_dim]` normalised observations.
    pub obs: Tensor,
    /// `[n, 1]` eps.
    pub eps: Tensor,
    /// `[n, K]` code fed when acting.
    pub code: Tensor,
    /// `[n, K]` Gumbel noise the code was drawn with.
    pub gumbel: Tensor,
    /// `[n, act_dim]` pre-tanh action samples.
    pub pre_tanh: Tensor,
    /// `[n]` log-density under the acting policy.
    pub old_logp: Tensor,
    /// `[n]` advantages (normalised here).
    pub adv: Tensor,
    /// `[n]` value targets.
    pub returns: Tensor,
}

/// Statistics of one PPO update.
#[derive(Debug, Clone, Default)]
pub struct PpoStats {
    /// Mean clipped surrogate loss.
    pub policy_loss: f64,
    /// Mean value loss.
    pub value_loss: f64,
    /// Policy entropy.
    pub entropy: f64,
    /// Mean approximate KL(old || new).
    pub approx_kl: f64,
    /// Fraction of clipped ratios.
    pub clip_frac: f64,
}

/// The learner side of PPO: networks and their optimisers.
pub struct PpoLearner {
    /// Policy.
    pub policy: Policy,
    /// Value network.
    pub value: Mlp,
    /// Logits of p(c) `[K]`.
    pub prior_logits: Tensor,
    /// Optimiser of policy and value.
    pub opt: Adam,
    /// Optimiser of the p(c) logits (stepped only with the Gumbel prior).
    pub prior_opt: Adam,
    cfg: PpoConfig,
    prior: LatentPrior,
    tau: f64,
}

impl PpoLearner {
    /// Builds networks in `vs` (policy + value) and `prior_vs` (logits).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        vs: &nn::VarStore,
        prior_vs: &nn::VarStore,
        input: usize,
        act_dim: usize,
        n_codes: usize,
        cfg: &PpoConfig,
        prior: LatentPrior,
        tau: f64,
    ) -> Result<Self, tch::TchError> {
        let root = vs.root();
        let policy = Policy::new(&root / "pi", input, &cfg.hidden, act_dim, cfg.log_std_init);
        let mut vsizes = vec![input];
        vsizes.extend_from_slice(&cfg.hidden);
        vsizes.push(1);
        let value = Mlp::new(&root / "v", &vsizes, false, 1.0);
        let prior_logits = prior_vs.root().zeros("prior_logits", &[n_codes as i64]);
        let opt = Adam::new(vs, cfg.lr)?;
        let prior_opt = Adam::new(prior_vs, cfg.prior_lr.max(1e-12))?;
        Ok(Self {
            policy,
            value,
            prior_logits,
            opt,
            prior_opt,
            cfg: cfg.clone(),
            prior,
            tau,
        })
    }

    /// The code fed to the networks for a batch: recomputed from Gumbel noise (with
    /// gradient to the prior logits) or the stored one.
    pub fn code_for(&self, code: &Tensor, gumbel: &Tensor) -> Tensor {
        match self.prior {
            LatentPrior::Gumbel => {
                let logp = self.prior_logits.log_softmax(-1, Kind::Float);
                ((gumbel + logp) / self.tau).softmax(-1, Kind::Float)
            }
            _ => code.shallow_clone(),
        }
    }

    /// `V(s, eps, c)` for a batch of inputs `[n, in]`.
    pub fn values(&self, input: &Tensor) -> Tensor {
        self.value.forward(input).squeeze_dim(-1)
    }

    /// Runs `epochs` epochs of minibatch updates on tch.
    pub fn update(&mut self, b: &PpoBatch, rng: &mut ChaCha8Rng) -> PpoStats {
        // Only the fused path can fail (an operand of the wrong shape).
        self.update_on(b, rng, None).unwrap_or_default()
    }

    /// Runs `epochs` epochs of minibatch updates, on the fused backend when given
    /// ([`crate::fused::ppo`]), else on tch; both draw the same minibatches.
    pub fn update_on(
        &mut self,
        b: &PpoBatch,
        rng: &mut ChaCha8Rng,
        fused: Option<&mut crate::fused::Fused>,
    ) -> Result<PpoStats, crate::fused::FusedError> {
        let n = b.old_logp.size()[0] as usize;
        let adv = {
            let m = b.adv.mean(Kind::Float);
            let s = b.adv.std(true).clamp_min(1e-8);
            (&b.adv - m) / s
        };
        // Every per-row input in one matrix, so a minibatch is one gather; the
        // columns are views of it.
        let rows = PpoRows::new(b, &adv);
        let mut idx: Vec<i64> = (0..n as i64).collect();
        let mb = self.cfg.minibatch.min(n).max(1);
        let mut sums = Vec::new();
        let train_prior = self.prior == LatentPrior::Gumbel && self.cfg.prior_lr > 0.0;
        if let Some(f) = fused {
            return self.fused_epochs(f, &rows, &mut idx, mb, train_prior, rng);
        }
        for _ in 0..self.cfg.epochs {
            idx.shuffle(rng);
            for chunk in idx.chunks(mb) {
                let r = rows.gather(&Tensor::from_slice(chunk));
                let code = self.code_for(&r.code, &r.gumbel);
                let input = Tensor::cat(&[&r.obs_eps, &code], 1);
                let logp = self.policy.log_prob(&input, &r.pre_tanh);
                let log_ratio = &logp - &r.old_logp;
                let ratio = log_ratio.exp();
                let clip = self.cfg.clip;
                let s1 = &ratio * &r.adv;
                let s2 = ratio.clamp(1.0 - clip, 1.0 + clip) * &r.adv;
                let policy_loss = -s1.minimum(&s2).mean(Kind::Float);
                // The value net sees the codes without their path to p(c).
                let v = self.values(&input.detach());
                let value_loss = (v - &r.returns).square().mean(Kind::Float);
                let entropy = self.policy.entropy();
                let loss = &policy_loss + &value_loss * self.cfg.value_coef
                    - &entropy * self.cfg.entropy_coef;
                self.opt.zero_grad();
                if train_prior {
                    self.prior_opt.zero_grad();
                }
                loss.backward();
                self.opt.clip_and_step(self.cfg.max_grad_norm);
                if train_prior {
                    self.prior_opt.step();
                }
                sums.push(tch::no_grad(|| {
                    let kl = ((&ratio - 1.0) - &log_ratio).mean(Kind::Float);
                    let clipped = (ratio - 1.0).abs().gt(clip).to_kind(Kind::Float);
                    Tensor::stack(
                        &[
                            policy_loss,
                            value_loss,
                            entropy,
                            kl,
                            clipped.mean(Kind::Float),
                        ],
                        0,
                    )
                }));
            }
        }
        if sums.is_empty() {
            return Ok(PpoStats::default());
        }
        // One read of the statistics for the whole update.
        let mean = crate::train::nets::tensor_to_vec(&Tensor::stack(&sums, 0).mean_dim(
            0,
            false,
            Kind::Float,
        ));
        let at = |i: usize| mean.get(i).copied().map_or(f64::NAN, f64::from);
        Ok(PpoStats {
            policy_loss: at(0),
            value_loss: at(1),
            entropy: at(2),
            approx_kl: at(3),
            clip_frac: at(4),
        })
    }

    /// The epochs of [`PpoLearner::update_on`] on the fused backend.
    fn fused_epochs(
        &mut self,
        f: &mut crate::fused::Fused,
        rows: &PpoRows,
        idx: &mut [i64],
        mb: usize,
        train_prior: bool,
        rng: &mut ChaCha8Rng,
    ) -> Result<PpoStats, crate::fused::FusedError> {
        use crate::fused::ppo::{PpoSettings, RowLayout};
        let data = crate::fused::floats(&rows.all)?;
        let [oe, k, _, act] = rows.widths.map(|w| w as usize);
        let lay = RowLayout {
            obs_eps: oe,
            k,
            act,
        };
        let c = &self.cfg;
        let s = PpoSettings {
            clip: c.clip,
            value_coef: c.value_coef as f32,
            entropy_coef: c.entropy_coef as f32,
            max_grad_norm: c.max_grad_norm,
            gumbel_tau: self.gumbel_tau().map(|t| t as f32),
            train_prior,
        };
        let mut sum = PpoStats::default();
        let mut steps = 0usize;
        for _ in 0..self.cfg.epochs {
            idx.shuffle(rng);
            for chunk in idx.chunks(mb) {
                let (mut opt, mut prior) = (self.opt.flat_mut(), self.prior_opt.flat_mut());
                let st = f.ppo.step(
                    &f.team, &f.policy, &mut opt, &mut prior, data, lay, chunk, &s,
                )?;
                sum.policy_loss += st.policy_loss;
                sum.value_loss += st.value_loss;
                sum.entropy += st.entropy;
                sum.approx_kl += st.approx_kl;
                sum.clip_frac += st.clip_frac;
                steps += 1;
            }
        }
        let d = steps.max(1) as f64;
        Ok(PpoStats {
            policy_loss: sum.policy_loss / d,
            value_loss: sum.value_loss / d,
            entropy: sum.entropy / d,
            approx_kl: sum.approx_kl / d,
            clip_frac: sum.clip_frac / d,
        })
    }

    /// One score-function step on the p(c) logits: the code of each step
    /// (`argmax c`, distributed as p(c) by the Gumbel-max trick) is reinforced by that
    /// step's `reward` minus the batch mean. Ascends `E_{k~p}[r]`.
    pub fn prior_score_step(&mut self, code: &Tensor, reward: &Tensor, coef: f64) {
        let k = code.argmax(-1, false);
        let adv = tch::no_grad(|| {
            let m = reward.mean(Kind::Float);
            let s = reward.std(true).clamp_min(1e-8);
            (reward - m) / s
        });
        let logp = self
            .prior_logits
            .log_softmax(-1, Kind::Float)
            .index_select(0, &k);
        let loss = -(logp * adv).mean(Kind::Float) * coef;
        self.prior_opt.zero_grad();
        loss.backward();
        self.prior_opt.step();
    }

    /// One step of the p(c) logits toward Q_c's mean label prediction on a batch of
    /// unlabeled demonstrations (`expert_qc_logits`, not moved by this step): the
    /// minimum over p(c) of KL(mean Q_c || p(c)), L_RIM's second term (Eq. 8-9).
    pub fn prior_follow_step(&mut self, expert_qc_logits: &Tensor) {
        let marginal = tch::no_grad(|| {
            expert_qc_logits
                .softmax(-1, Kind::Float)
                .mean_dim(0, false, Kind::Float)
        });
        let log_p = self.prior_logits.log_softmax(-1, Kind::Float);
        let loss = -(marginal * log_p).sum(Kind::Float);
        self.prior_opt.zero_grad();
        loss.backward();
        self.prior_opt.step();
    }

    /// The configuration it was built with.
    pub fn config(&self) -> &PpoConfig {
        &self.cfg
    }

    /// How the codes reach the networks: the Gumbel prior recomputes them from their
    /// noise with this temperature (`Some`), the others feed the stored ones.
    pub fn gumbel_tau(&self) -> Option<f64> {
        (self.prior == LatentPrior::Gumbel).then_some(self.tau)
    }

    /// p(c) as probabilities.
    pub fn prior_probs(&self) -> Vec<f32> {
        tch::no_grad(|| {
            crate::train::nets::tensor_to_vec(&self.prior_logits.softmax(-1, Kind::Float))
        })
    }
}

/// A [`PpoBatch`] as one `[n, cols]` matrix (advantages normalised), gathered per
/// minibatch into [`MinibatchRows`].
struct PpoRows {
    all: Tensor,
    /// Widths of obs + eps, code, gumbel, pre_tanh.
    widths: [i64; 4],
}

/// One minibatch's columns (views of one gathered matrix).
struct MinibatchRows {
    obs_eps: Tensor,
    code: Tensor,
    gumbel: Tensor,
    pre_tanh: Tensor,
    old_logp: Tensor,
    adv: Tensor,
    returns: Tensor,
}

impl PpoRows {
    fn new(b: &PpoBatch, adv: &Tensor) -> Self {
        let col = |t: &Tensor| t.view([-1, 1]);
        let parts = [
            b.obs.shallow_clone(),
            b.eps.shallow_clone(),
            b.code.shallow_clone(),
            b.gumbel.shallow_clone(),
            b.pre_tanh.shallow_clone(),
            col(&b.old_logp),
            col(adv),
            col(&b.returns),
        ];
        let w = |t: &Tensor| t.size()[1];
        Self {
            widths: [
                w(&b.obs) + w(&b.eps),
                w(&b.code),
                w(&b.gumbel),
                w(&b.pre_tanh),
            ],
            all: Tensor::cat(&parts, 1),
        }
    }

    fn gather(&self, idx: &Tensor) -> MinibatchRows {
        let m = self.all.index_select(0, idx);
        let [oe, c, g, p] = self.widths;
        let tail = oe + c + g + p;
        MinibatchRows {
            obs_eps: m.narrow(1, 0, oe),
            code: m.narrow(1, oe, c),
            gumbel: m.narrow(1, oe + c, g),
            pre_tanh: m.narrow(1, oe + c + g, p),
            old_logp: m.select(1, tail),
            adv: m.select(1, tail + 1),
            returns: m.select(1, tail + 2),
        }
    }
}

/// Builds `[n, 1]` from a slice.
pub fn column(v: &[f32]) -> Tensor {
    tensor_2d(v, 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gae_matches_a_hand_computed_case() {
        // 3 steps, terminal at the end; gamma 0.9, lambda 0.5.
        let r = [1.0, 0.0, 2.0];
        let v = [0.5, 1.0, 1.5];
        let nv = [1.0, 1.5, 9.0]; // last is ignored: terminated
        let term = [false, false, true];
        let cut = [false, false, false];
        let (adv, ret) = gae(&r, &v, &nv, &term, &cut, 0.9, 0.5);
        // deltas: d2 = 2 - 1.5 = 0.5; d1 = 0 + .9*1.5 - 1 = 0.35; d0 = 1 + .9*1 - .5 = 1.4
        // A2 = .5; A1 = .35 + .45*.5 = .575; A0 = 1.4 + .45*.575 = 1.65875
        let want = [1.65875, 0.575, 0.5];
        for (a, w) in adv.iter().zip(want) {
            assert!((a - w).abs() < 1e-6, "{adv:?}");
        }
        assert!((ret[0] - (1.65875 + 0.5)).abs() < 1e-6);
    }

    #[test]
    fn gae_bootstraps_and_stops_at_a_cut() {
        let r = [0.0, 0.0];
        let v = [0.0, 0.0];
        let nv = [0.0, 2.0];
        let (adv, _) = gae(&r, &v, &nv, &[false, false], &[true, true], 0.5, 1.0);
        // Step 0 is cut: no carry from step 1 even though lambda = 1.
        assert_eq!(adv, vec![0.0, 1.0]);
    }

    fn tiny_batch(n: usize, k: usize) -> PpoBatch {
        let f = |v: Vec<f32>, c: usize| tensor_2d(&v, c);
        let mut g = Vec::new();
        let mut code = Vec::new();
        for i in 0..n {
            for j in 0..k {
                g.push(((i * 7 + j * 3) % 5) as f32 * 0.3 - 0.6);
                code.push(if j == i % k { 1.0 } else { 0.0 });
            }
        }
        PpoBatch {
            obs: f((0..n * 2).map(|i| (i as f32 * 0.37).sin()).collect(), 2),
            eps: f((0..n).map(|i| (i as f32 * 0.11).cos()).collect(), 1),
            code: f(code, k),
            gumbel: f(g, k),
            pre_tanh: f((0..n).map(|i| (i as f32 * 0.53).sin()).collect(), 1),
            old_logp: Tensor::from_slice(&vec![-1.0f32; n]),
            adv: Tensor::from_slice(&(0..n).map(|i| (i % k) as f32 - 1.0).collect::<Vec<_>>()),
            returns: Tensor::from_slice(&vec![0.5f32; n]),
        }
    }

    fn prior_after_update(prior: LatentPrior) -> Vec<f32> {
        use rand::SeedableRng;
        tch::manual_seed(0);
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let pvs = nn::VarStore::new(tch::Device::Cpu);
        let cfg = PpoConfig {
            epochs: 2,
            minibatch: 16,
            ..PpoConfig::default()
        };
        let mut l = PpoLearner::new(&vs, &pvs, 2 + 1 + 3, 1, 3, &cfg, prior, 0.5).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let stats = l.update(&tiny_batch(48, 3), &mut rng);
        assert!(stats.policy_loss.is_finite() && stats.value_loss.is_finite());
        crate::train::nets::tensor_to_vec(&l.prior_logits)
    }

    #[test]
    fn gumbel_softmax_gradient_reaches_the_prior_logits_through_ppo() {
        let logits = prior_after_update(LatentPrior::Gumbel);
        assert!(logits.iter().any(|x| x.abs() > 1e-6), "{logits:?}");
    }

    #[test]
    fn a_fixed_uniform_prior_is_never_updated() {
        assert_eq!(prior_after_update(LatentPrior::Uniform), vec![0.0; 3]);
    }

    #[test]
    fn p_of_c_follows_the_encoders_label_marginal() {
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let pvs = nn::VarStore::new(tch::Device::Cpu);
        let cfg = PpoConfig {
            prior_lr: 0.05,
            ..PpoConfig::default()
        };
        let mut l = PpoLearner::new(&vs, &pvs, 5, 1, 3, &cfg, LatentPrior::Gumbel, 0.1).unwrap();
        // Q_c's predictions on four demonstrations: mean (0.7, 0.25, 0.05).
        let probs = tensor_2d(
            &[
                0.9, 0.05, 0.05, 0.9, 0.05, 0.05, 0.5, 0.45, 0.05, 0.5, 0.45, 0.05,
            ],
            3,
        );
        let qc_logits = probs.log();
        for _ in 0..600 {
            l.prior_follow_step(&qc_logits);
        }
        let p = l.prior_probs();
        for (got, want) in p.iter().zip([0.7f32, 0.25, 0.05]) {
            assert!((got - want).abs() < 0.01, "{p:?}");
        }
    }

    #[test]
    fn score_step_moves_p_of_c_toward_the_rewarded_code() {
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let pvs = nn::VarStore::new(tch::Device::Cpu);
        let cfg = PpoConfig {
            prior_lr: 0.05,
            ..PpoConfig::default()
        };
        let mut l = PpoLearner::new(&vs, &pvs, 4, 1, 2, &cfg, LatentPrior::Gumbel, 0.1).unwrap();
        // Code 0 steps earn 1, code 1 steps earn 0.
        let code = tensor_2d(&[1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0], 2);
        let reward = Tensor::from_slice(&[1.0f32, 0.0, 1.0, 0.0]);
        for _ in 0..20 {
            l.prior_score_step(&code, &reward, 1.0);
        }
        let p = l.prior_probs();
        assert!(p[0] > 0.6, "{p:?}");
    }
}
