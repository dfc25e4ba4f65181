//! The stages' fused variants ([`crate::fused`], `learner.backend = "fused"`): the
//! run's tensors and optimisers handed to the fused passes, and what the tch stages
//! do around a D/Q step (Q_c's running marginal, p(c)'s steps, the logged terms)
//! done with the fused step's report.

use super::data::Rollout;
use super::{IterationLog, Trainer};
use crate::fused::disc::{DiscDraw, DiscReport, DiscSources};
use crate::fused::reward::RewardInputs;
use crate::fused::{FusedError, floats, longs, ppo::log_softmax};
use crate::objective::combined::{DiscWeights, instance_noise};
use crate::objective::reward::RewardWeights;
use anyhow::{Context, Result};
use ess_proto::config::{LatentPrior, RolloutCodes};
use tch::{Kind, Tensor};

/// The gradient of a loss with respect to `log_softmax(logits)` carried to `logits`.
fn through_log_softmax(logits: &[f32], dlog_p: &[f32]) -> Vec<f32> {
    let lp = log_softmax(logits);
    let total: f32 = dlog_p.iter().sum();
    lp.iter()
        .zip(dlog_p)
        .map(|(&l, &d)| d - l.exp() * total)
        .collect()
}

impl Trainer<'_> {
    /// One D/Q step on the fused backend with the draws `[generated, expert,
    /// labeled]`; `log` receives the step's terms (the last step of an iteration).
    pub(super) fn fused_disc_step(
        &mut self,
        r: &Rollout,
        w: &DiscWeights,
        [gi, ei, li]: [&[i64]; 3],
        log: Option<&mut IterationLog>,
    ) -> Result<()> {
        let m = &self.cfg.method;
        let uniform_rollouts = m.rollout_codes == RolloutCodes::Uniform;
        let prior_from_rim =
            m.prior == LatentPrior::Gumbel && m.rim_prior_grad && !uniform_rollouts;
        let fused = self.fused.as_mut().context("no fused backend")?;
        // Instance noise, then the contrastive copies' noise, from libtorch's generator,
        // as `disc_objective` draws them (same numbers on both backends).
        let inp = fused.disc_net.inp() as i64;
        let instance = (w.input_noise > 0.0)
            .then(|| instance_noise((gi.len() + ei.len()) as i64, inp, w.input_noise));
        let n_con = if w.contrastive > 0.0 {
            w.contrastive_batch.min(ei.len())
        } else {
            0
        };
        let noise = (n_con > 0).then(|| {
            let shape = [n_con as i64, fused.disc_net.inp() as i64];
            Tensor::randn(shape, (Kind::Float, tch::Device::Cpu)) * w.contrastive_noise
        });
        let e = &self.expert;
        let src = DiscSources {
            gen_x: floats(&r.disc_x)?,
            gen_code: floats(&r.code)?,
            gen_eps: floats(&r.eps)?,
            expert_x: floats(&e.unlabeled)?,
            expert_mode: longs(&e.unlabeled_mode)?,
            labeled_x: floats(&e.labeled)?,
            labels: longs(&e.labels)?,
        };
        let draw = DiscDraw {
            gen_: gi,
            expert: ei,
            labeled: li,
            noise: match &noise {
                Some(t) => floats(t)?,
                None => &[],
            },
            instance_noise: match &instance {
                Some(t) => floats(t)?,
                None => &[],
            },
            report: log.is_some(),
        };
        let logits = floats(&self.nets.ppo.prior_logits)?.to_vec();
        let log_prior = log_softmax(&logits);
        let mut opt = self.nets.dopt.flat_mut();
        let rep = fused
            .disc
            .step(
                &fused.team,
                &fused.disc_net,
                &mut opt,
                &src,
                &draw,
                w,
                &log_prior,
            )
            .map_err(FusedError::from)?;
        if m.disc_code_reweight {
            for (q, p) in self.st.qc_marginal.iter_mut().zip(&rep.expert_marginal) {
                *q = 0.99 * *q + 0.01 * p;
            }
        }
        let prior = &mut self.nets.ppo.prior_opt;
        if uniform_rollouts {
            // p(c) one step toward Q_c's label marginal: -sum_k m_k log p_k.
            let dlp: Vec<f32> = rep.expert_marginal.iter().map(|&x| -(x as f32)).collect();
            prior.flat_mut().step(&through_log_softmax(&logits, &dlp));
        }
        if prior_from_rim && w.rim > 0.0 {
            prior
                .flat_mut()
                .step(&through_log_softmax(&logits, &rep.dlog_prior));
        }
        if let Some(log) = log {
            log_report(&rep, log);
        }
        Ok(())
    }

    /// [`Trainer::policy_rewards`]'s rewards, `V(s)` and `V(s')` back to back, and D's
    /// reward term, on the fused backend.
    pub(super) fn fused_rewards(
        &mut self,
        rw: RewardWeights,
        r: &Rollout,
        next_n: &Tensor,
    ) -> Result<(Vec<f32>, Vec<f32>, Tensor)> {
        let fused = self.fused.as_mut().context("no fused backend")?;
        let inputs = RewardInputs {
            disc_x: floats(&r.disc_x)?,
            code: floats(&r.code)?,
            eps: floats(&r.eps)?,
            obs: floats(&r.obs_n)?,
            next_obs: floats(next_n)?,
        };
        let dp = self.nets.dopt.flat_mut();
        let vp = self.nets.ppo.opt.flat_mut();
        let value = &fused.policy.value;
        let out = fused
            .reward
            .run(
                &fused.team,
                &fused.disc_net,
                dp.params,
                value,
                vp.params,
                &inputs,
                rw,
            )
            .map_err(FusedError::from)?;
        let mut values = out.values;
        values.extend_from_slice(&out.next_values);
        Ok((out.reward, values, Tensor::from_slice(&out.disc_term)))
    }
}

/// The last D/Q step's losses and accuracies into the iteration's row (as the tch
/// path's `log_disc_terms`).
fn log_report(r: &DiscReport, log: &mut IterationLog) {
    let opt = |v: Option<f64>| v.unwrap_or(0.0);
    log.disc_bce = r.bce;
    log.qeps = opt(r.qeps);
    log.qc_generated = opt(r.qc_generated);
    log.qc_labeled = opt(r.qc_labeled);
    log.rim_entropy = opt(r.rim_entropy);
    log.rim_kl = opt(r.rim_kl);
    log.contrastive = opt(r.contrastive);
    log.d_acc_expert = r.d_acc_expert;
    log.d_acc_policy = r.d_acc_policy;
}
