//! The stages of one iteration of Algorithm 1, each a [`Trainer`] method.

use super::data::{CodeReweight, Rollout, sample_idx};
use super::records::prior_string;
use super::{IterationLog, Trainer};
use crate::eval::EvalResult;
use crate::objective::combined::{DiscBatch, DiscTerms, DiscWeights, disc_objective};
use crate::objective::reward::{RewardWeights, disc_term, policy_reward};
use crate::train::nets::{export_policy, tensor_2d, tensor_to_vec};
use crate::train::ppo::{PpoBatch, rollout_gae};
use anyhow::{Context, Result};
use ess_actor::{EvalEpisode, LocalEval, PolicyWeights};
use ess_proto::config::{LatentPrior, RolloutCodes};
use std::sync::Arc;
use std::time::Instant;
use tch::{Kind, Tensor};

/// The policy's per-step rewards (Eq. 9's policy terms plus the env's) and the value
/// estimates GAE needs.
pub struct Rewards {
    /// Per-step reward.
    pub reward: Vec<f32>,
    /// `V(s_t)`.
    pub values: Vec<f32>,
    /// `V(s_{t+1})`.
    pub next_values: Vec<f32>,
}

fn scalar(t: &Tensor) -> f64 {
    f64::try_from(t).unwrap_or(f64::NAN)
}

impl Trainer<'_> {
    /// The current policy as the actors run it, tagged `version`, with the logits the
    /// actors draw codes from: p(c)'s, or zeros under `method.rollout_codes =
    /// "uniform"`.
    pub fn weights(&self, version: u64) -> Result<PolicyWeights> {
        let n = &self.norm;
        let p = &self.nets.ppo;
        let logits = match self.cfg.method.rollout_codes {
            RolloutCodes::Prior => p.prior_logits.shallow_clone(),
            RolloutCodes::Uniform => p.prior_logits.zeros_like(),
        };
        Ok(export_policy(&p.policy, &logits, &n.mean, &n.std, version)?)
    }

    /// The probabilities the rollouts' codes were drawn with.
    fn rollout_code_probs(&self) -> Vec<f32> {
        match self.cfg.method.rollout_codes {
            RolloutCodes::Prior => self.nets.ppo.prior_probs(),
            RolloutCodes::Uniform => vec![1.0 / self.dims.codes as f32; self.dims.codes],
        }
    }

    /// With `method.disc_code_reweight`, the code proportions D's generated batch is
    /// drawn at instead of the rollout's: the demos' mode marginal as p(c) holds it
    /// under uniform rollouts, else Q_c's running estimate of it.
    fn disc_code_target(&self) -> Option<Vec<f64>> {
        let m = &self.cfg.method;
        if !m.disc_code_reweight {
            return None;
        }
        Some(match m.rollout_codes {
            RolloutCodes::Uniform => {
                let p = self.nets.ppo.prior_probs();
                p.iter().map(|&p| f64::from(p)).collect()
            }
            RolloutCodes::Prior => self.st.qc_marginal.clone(),
        })
    }

    /// Rolls out `run.rollout_steps` transitions under the current policy (version
    /// `it`), or on the first iteration of a resumed overlapped run under the weights
    /// the checkpoint recorded for it.
    pub fn collect(&mut self, it: usize) -> Result<Rollout> {
        let weights = match self.resume_weights.take() {
            Some(w) => w,
            None => Arc::new(self.weights(it as u64)?),
        };
        let steps = self.cfg.run.rollout_steps;
        let chunks = super::data::gather(self.actors()?, weights, steps)?;
        Ok(Rollout::new(chunks, &self.norm, self.dims))
    }

    /// The D/Q, reward and PPO stages on `rollout`, timed into `log`.
    pub fn update(&mut self, it: usize, rollout: &Rollout, log: &mut IterationLog) -> Result<()> {
        let t1 = Instant::now();
        self.update_discriminator(it, rollout, log)?;
        log.disc_s = t1.elapsed().as_secs_f64();
        let t2 = Instant::now();
        let rewards = self.policy_rewards(it, rollout, log)?;
        self.update_policy(rollout, &rewards, log)?;
        log.ppo_s = t2.elapsed().as_secs_f64();
        Ok(())
    }

    /// `disc.steps` steps of the D/Q side of Eq. 9 ([`disc_objective`]) on minibatches
    /// of the rollout and the demonstrations; with `method.rim_prior_grad`, RIM's KL
    /// term moves p(c) too (Eq. 9 minimises L_RIM over p(c)). On the fused backend
    /// each step is [`Trainer::fused_disc_step`] on the same draws.
    pub fn update_discriminator(
        &mut self,
        it: usize,
        r: &Rollout,
        log: &mut IterationLog,
    ) -> Result<()> {
        let cfg = self.cfg;
        let m = &cfg.method;
        let w = DiscWeights::at(m, it).with_disc(&cfg.disc);
        let uniform_rollouts = m.rollout_codes == RolloutCodes::Uniform;
        let prior_from_rim =
            m.prior == LatentPrior::Gumbel && m.rim_prior_grad && !uniform_rollouts;
        let batch = cfg.disc.batch as i64;
        let (n_gen, n_exp) = (r.len() as i64, self.expert.unlabeled.size()[0]);
        let n_lab = self.expert.labeled.size()[0];
        let draw = self
            .disc_code_target()
            .map(|t| CodeReweight::new(&r.all.code, self.dims.codes, &t));
        let no_rows = Tensor::zeros([0], (Kind::Int64, tch::Device::Cpu));
        for step in 0..cfg.disc.steps {
            let rng = &mut self.st.rng;
            let gi = match &draw {
                Some(d) => d.sample(rng, batch),
                None => sample_idx(rng, n_gen, batch),
            };
            let ei = sample_idx(rng, n_exp, batch);
            let li = if w.qc_labeled > 0.0 && n_lab > 0 {
                sample_idx(rng, n_lab, batch.min(n_lab))
            } else {
                Vec::new()
            };
            if self.fused.is_some() {
                let last = step + 1 == cfg.disc.steps;
                self.fused_disc_step(r, &w, [&gi, &ei, &li], last.then_some(&mut *log))?;
                continue;
            }
            let (gi, ei, li) = (
                Tensor::from_slice(&gi),
                Tensor::from_slice(&ei),
                Tensor::from_slice(&li),
            );
            let e = &self.expert;
            let mode = if w.qc_full_labels > 0.0 {
                e.unlabeled_mode.index_select(0, &ei)
            } else {
                no_rows.shallow_clone()
            };
            let b = DiscBatch {
                gen_x: &r.disc_x.index_select(0, &gi),
                gen_code: &r.code.index_select(0, &gi),
                gen_eps: &r.eps.index_select(0, &gi),
                expert_x: &e.unlabeled.index_select(0, &ei),
                expert_mode: &mode,
                labeled_x: &e.labeled.index_select(0, &li),
                labels: &e.labels.index_select(0, &li),
            };
            let log_prior = self.nets.ppo.prior_logits.log_softmax(-1, Kind::Float);
            let log_prior = if prior_from_rim {
                log_prior
            } else {
                log_prior.detach()
            };
            let terms = disc_objective(&self.nets.disc, &b, &w, &log_prior);
            if m.disc_code_reweight {
                self.track_qc_marginal(&terms.expert_qc_logits);
            }
            if uniform_rollouts {
                self.nets.ppo.prior_follow_step(&terms.expert_qc_logits);
            }
            let n = &mut self.nets;
            n.dopt.zero_grad();
            if prior_from_rim {
                n.ppo.prior_opt.zero_grad();
            }
            terms.loss.backward();
            n.dopt.step();
            if prior_from_rim && w.rim > 0.0 {
                n.ppo.prior_opt.step();
            }
            if step + 1 == cfg.disc.steps {
                log_disc_terms(&terms, log);
            }
        }
        Ok(())
    }

    /// Moves the running estimate of the demos' mode marginal toward Q_c's mean
    /// prediction on this batch of them (`method.disc_code_reweight`).
    fn track_qc_marginal(&mut self, expert_qc_logits: &Tensor) {
        let p = tensor_to_vec(&tch::no_grad(|| {
            expert_qc_logits
                .softmax(-1, Kind::Float)
                .mean_dim(0, false, Kind::Float)
        }));
        for (q, p) in self.st.qc_marginal.iter_mut().zip(&p) {
            *q = 0.99 * *q + 0.01 * f64::from(*p);
        }
    }

    /// The policy's reward for each transition from the updated heads (Eq. 9's policy
    /// terms, [`RewardWeights::at`]) plus the env's, the value estimates, and (with
    /// `method.prior_score_coef`) a score-function step of p(c). Logs the rollout.
    pub fn policy_rewards(
        &mut self,
        it: usize,
        r: &Rollout,
        log: &mut IterationLog,
    ) -> Result<Rewards> {
        let cfg = self.cfg;
        let m = &cfg.method;
        let rw = RewardWeights::at(m, it, &self.rollout_code_probs());
        let next_n = self.norm.apply(&r.all.next_obs);
        let n = r.len();
        let (reward, values, disc_r) = if self.fused.is_some() {
            self.fused_rewards(rw, r, &next_n)?
        } else {
            self.tch_rewards(rw, r, &next_n)
        };
        let ppo = &mut self.nets.ppo;
        if m.prior == LatentPrior::Gumbel && m.prior_score_coef > 0.0 {
            ppo.prior_score_step(&r.code, &disc_r, m.prior_score_coef);
        }
        // The env's mode-agnostic shared reward, weighted (0 by default).
        let shared = m.reward_shared as f32;
        let reward: Vec<f32> = reward
            .iter()
            .zip(&r.all.env_reward)
            .map(|(r, e)| r + shared * e)
            .collect();
        log.reward_mean =
            reward.iter().map(|&r| r as f64).sum::<f64>() / reward.len().max(1) as f64;
        self.sink.rollout(it, &r.chunks, &reward)?;
        let (values, next_values) = values.split_at(n);
        Ok(Rewards {
            reward,
            values: values.to_vec(),
            next_values: next_values.to_vec(),
        })
    }

    /// [`Trainer::policy_rewards`]'s rewards (Eq. 9's policy terms), `V(s)` and
    /// `V(s')` back to back, and D's reward term, on tch.
    fn tch_rewards(
        &self,
        rw: RewardWeights,
        r: &Rollout,
        next_n: &Tensor,
    ) -> (Vec<f32>, Vec<f32>, Tensor) {
        let eps = r.eps.view([-1, 1]);
        tch::no_grad(|| {
            let o = self.nets.disc.forward(&r.disc_x);
            let reward = policy_reward(rw, &o.d_logit, &o.qc_logits, &r.code, &o.qeps, &r.eps);
            // V(s) and V(s') in one pass of the value net.
            let vin = Tensor::cat(
                &[
                    Tensor::cat(&[&r.obs_n, &eps, &r.code], 1),
                    Tensor::cat(&[next_n, &eps, &r.code], 1),
                ],
                0,
            );
            let v = tensor_to_vec(&self.nets.ppo.values(&vin));
            (tensor_to_vec(&reward), v, disc_term(rw, &o.d_logit))
        })
    }

    /// GAE, then PPO on policy and value; with the Gumbel prior, p(c) through the
    /// recomputed codes (Sec. 3.2, [`crate::train::ppo`]).
    pub fn update_policy(
        &mut self,
        r: &Rollout,
        rw: &Rewards,
        log: &mut IterationLog,
    ) -> Result<()> {
        let (ad, k) = (self.dims.act, self.dims.codes);
        let (adv, ret) = rollout_gae(
            &self.cfg.ppo,
            &mut self.st.scaler,
            &r.chunks,
            &rw.reward,
            &rw.values,
            &rw.next_values,
        );
        let batch = PpoBatch {
            obs: r.obs_n.shallow_clone(),
            eps: r.eps.view([-1, 1]),
            code: r.code.shallow_clone(),
            gumbel: tensor_2d(&r.all.gumbel, k),
            pre_tanh: tensor_2d(&r.all.pre_tanh, ad),
            old_logp: Tensor::from_slice(&r.all.logp),
            adv: Tensor::from_slice(&adv),
            returns: Tensor::from_slice(&ret),
        };
        let ppo = &mut self.nets.ppo;
        let st = ppo.update_on(&batch, &mut self.st.rng, self.fused.as_mut())?;
        // DAPG-style auxiliary cloning of the labeled few ([`super::bc`]).
        let (steps, mb) = (self.cfg.ppo.bc_steps_per_iter, self.cfg.ppo.minibatch);
        let (labeled, use_eps) = (&self.demos.labeled, self.cfg.method.use_eps);
        let at = (self.dims, use_eps);
        super::bc::clone_steps(ppo, labeled, &self.norm, at, (steps, mb), &mut self.st.rng);
        // The same on the unlabeled demonstrations, under Q_c's codes.
        let steps = self.cfg.ppo.bc_unlabeled_steps_per_iter;
        let qc = super::bc::qc_logits(&self.nets.disc);
        let draw = if self.cfg.ppo.bc_unlabeled_balanced {
            super::bc::EncodedDraw::Balanced
        } else {
            super::bc::EncodedDraw::Proportional
        };
        let enc = (&qc as super::bc::QcFn<'_>, &self.expert.unlabeled, draw);
        let unlabeled = &self.demos.unlabeled;
        let rng = &mut self.st.rng;
        super::bc::clone_encoded_steps(ppo, enc, unlabeled, &self.norm, at, (steps, mb), rng);
        log.policy_loss = st.policy_loss;
        log.value_loss = st.value_loss;
        log.entropy = st.entropy;
        log.approx_kl = st.approx_kl;
        log.prior = prior_string(&ppo.prior_probs());
        Ok(())
    }

    /// The paper's evaluation of the current policy (version `it`): `episodes` per code,
    /// in the actor processes when they offer it, else in this process.
    pub fn evaluate(
        &mut self,
        it: usize,
        episodes: usize,
        seed: u64,
    ) -> Result<(EvalResult, Vec<EvalEpisode>)> {
        let w = self.weights(it as u64)?;
        let (reference, latent) = (&self.reference, &self.latent);
        let actors = self
            .actors
            .as_deref_mut()
            .context("the actors are collecting")?;
        match actors.evaluator() {
            Some(runner) => crate::eval::evaluate(reference, runner, &w, latent, episodes, seed),
            None => {
                let mut local = LocalEval(self.eval_env.as_mut());
                crate::eval::evaluate(reference, &mut local, &w, latent, episodes, seed)
            }
        }
    }
}

/// The last D/Q step's losses and accuracies into the iteration's row.
fn log_disc_terms(t: &DiscTerms, log: &mut IterationLog) {
    let opt = |v: &Option<Tensor>| v.as_ref().map(scalar).unwrap_or(0.0);
    tch::no_grad(|| {
        log.disc_bce = scalar(&t.bce);
        log.qeps = opt(&t.qeps);
        log.qc_generated = opt(&t.qc_generated);
        log.qc_labeled = opt(&t.qc_labeled);
        log.rim_entropy = opt(&t.rim_entropy);
        log.rim_kl = opt(&t.rim_kl);
        log.contrastive = opt(&t.contrastive);
        let acc = |t: &Tensor| scalar(&t.to_kind(Kind::Float).mean(Kind::Float));
        log.d_acc_expert = acc(&t.expert_logit.gt(0.0));
        log.d_acc_policy = acc(&t.policy_logit.le(0.0));
    });
}
