//! Range checks of every section: [`TrainConfig::check`] turns a merged configuration
//! into a [`CheckedConfig`]; each error names the first key out of range.

use super::{
    ActorTransport, CheckedConfig, ConfigError, DemosConfig, DiscConfig, EnvConfig, LatentPrior,
    MethodConfig, PpoConfig, RolloutCodes, RunConfig, SacConfig, TrainConfig,
};

pub(super) fn range<T: std::fmt::Display>(
    ok: bool,
    key: &str,
    value: T,
    reason: &str,
) -> Result<(), ConfigError> {
    if ok {
        Ok(())
    } else {
        Err(ConfigError::OutOfRange {
            key: key.into(),
            value: value.to_string(),
            reason: reason.into(),
        })
    }
}

fn finite_nonneg(key: &str, v: f64) -> Result<(), ConfigError> {
    range(v.is_finite() && v >= 0.0, key, v, "must be finite and >= 0")
}

fn finite_pos(key: &str, v: f64) -> Result<(), ConfigError> {
    range(v.is_finite() && v > 0.0, key, v, "must be finite and > 0")
}

impl TrainConfig {
    /// Checks every value once; the error names the first key out of range.
    pub fn check(mut self) -> Result<CheckedConfig, ConfigError> {
        if self.run.actors == 0 {
            self.run.actors = 1;
            self.run.transport = ActorTransport::Threads;
        }
        self.env.check()?;
        self.demos.check()?;
        self.method.check()?;
        self.ppo.check()?;
        self.sac.check()?;
        self.disc.check()?;
        self.run.check()?;
        self.remote.check()?;
        range(
            self.ppo.bc_unlabeled_steps_per_iter == 0
                || (self.method.prior != LatentPrior::None && self.method.w_qc_labeled > 0.0),
            "ppo.bc_unlabeled_steps_per_iter",
            self.ppo.bc_unlabeled_steps_per_iter,
            "needs a Q_c trained on the labeled demonstrations (method.w_qc_labeled > 0 \
             and a latent code) to read the unlabeled rows' codes",
        )?;
        Ok(CheckedConfig(self))
    }
}

impl EnvConfig {
    pub(super) fn check(&self) -> Result<(), ConfigError> {
        let e = self;
        range(
            !e.name.is_empty(),
            "env.name",
            &e.name,
            "must name an environment",
        )?;
        range(e.n_modes >= 2, "env.n_modes", e.n_modes, "must be >= 2")?;
        Ok(())
    }
}

impl DemosConfig {
    pub(super) fn check(&self) -> Result<(), ConfigError> {
        let d = self;
        range(
            d.label_ratio.is_finite() && d.label_ratio > 0.0 && d.label_ratio <= 1.0,
            "demos.label_ratio",
            d.label_ratio,
            "must be in (0, 1]",
        )?;
        range(
            d.imbalance_ratio.is_finite() && d.imbalance_ratio >= 1.0,
            "demos.imbalance_ratio",
            d.imbalance_ratio,
            "must be finite and >= 1",
        )?;
        range(
            d.majority_episodes >= 1,
            "demos.majority_episodes",
            d.majority_episodes,
            "must be >= 1",
        )?;
        Ok(())
    }
}

impl MethodConfig {
    pub(super) fn check(&self) -> Result<(), ConfigError> {
        let m = self;
        finite_pos("method.gumbel_tau", m.gumbel_tau)?;
        for (k, v) in [
            ("method.w_disc", m.w_disc),
            ("method.w_grad_penalty", m.w_grad_penalty),
            ("method.w_qeps", m.w_qeps),
            ("method.w_qc_labeled", m.w_qc_labeled),
            ("method.w_qc_generated", m.w_qc_generated),
            ("method.w_qc_full_labels", m.w_qc_full_labels),
            ("method.w_contrastive", m.w_contrastive),
            ("method.contrastive_noise", m.contrastive_noise),
            ("method.w_rim", m.w_rim),
            ("method.rim_cond_entropy", m.rim_cond_entropy),
            ("method.rim_marginal_kl", m.rim_marginal_kl),
            ("method.rim_l2", m.rim_l2),
            ("method.reward_qc", m.reward_qc),
            ("method.reward_qeps", m.reward_qeps),
            ("method.reward_disc", m.reward_disc),
            ("method.reward_shared", m.reward_shared),
            ("method.prior_score_coef", m.prior_score_coef),
        ] {
            finite_nonneg(k, v)?;
        }
        finite_pos("method.contrastive_temperature", m.contrastive_temperature)?;
        finite_pos("method.disc_reward_temperature", m.disc_reward_temperature)?;
        range(
            m.contrastive_batch >= 2,
            "method.contrastive_batch",
            m.contrastive_batch,
            "must be >= 2",
        )?;
        range(
            m.prior != LatentPrior::None || (m.reward_qc == 0.0 && m.w_qc_generated == 0.0),
            "method.prior",
            "\"none\"",
            "a method without latent skill cannot reward or train Q_c on generated codes",
        )?;
        range(
            m.prior != LatentPrior::None || !m.disc_reward_qc_gate,
            "method.disc_reward_qc_gate",
            "true",
            "a method without latent skill has no code for Q_c to credit",
        )?;
        range(
            !m.qc_reward_floor || m.qc_reward_entropy,
            "method.qc_reward_floor",
            "true",
            "needs method.qc_reward_entropy = true (log Q_c alone is never above 0, so \
             the floor would zero the term)",
        )?;
        range(
            m.qc_reward_floor_at.is_finite() && m.qc_reward_floor_at <= 0.0,
            "method.qc_reward_floor_at",
            m.qc_reward_floor_at,
            "must be a finite number <= 0 (the floor clips log Q_c + H(c), which is \
             above 0 only where Q_c credits the step's code)",
        )?;
        range(
            m.qc_reward_floor || m.qc_reward_floor_at == 0.0,
            "method.qc_reward_floor_at",
            m.qc_reward_floor_at,
            "has no effect unless method.qc_reward_floor = true",
        )?;
        range(
            m.rollout_codes == RolloutCodes::Prior || m.prior == LatentPrior::Gumbel,
            "method.rollout_codes",
            "\"uniform\"",
            "needs a learned p(c) (method.prior = \"gumbel\") to weight the rollouts by",
        )?;
        Ok(())
    }
}

impl PpoConfig {
    pub(super) fn check(&self) -> Result<(), ConfigError> {
        let p = self;
        range(
            !p.hidden.is_empty() && !p.hidden.contains(&0),
            "ppo.hidden",
            format!("{:?}", p.hidden),
            "must list >= 1 width, all > 0",
        )?;
        finite_pos("ppo.lr", p.lr)?;
        finite_nonneg("ppo.prior_lr", p.prior_lr)?;
        range(p.epochs >= 1, "ppo.epochs", p.epochs, "must be >= 1")?;
        range(
            p.minibatch >= 1,
            "ppo.minibatch",
            p.minibatch,
            "must be >= 1",
        )?;
        range(
            p.clip.is_finite() && p.clip > 0.0 && p.clip < 1.0,
            "ppo.clip",
            p.clip,
            "must be in (0, 1)",
        )?;
        range(
            p.gamma.is_finite() && p.gamma > 0.0 && p.gamma <= 1.0,
            "ppo.gamma",
            p.gamma,
            "must be in (0, 1]",
        )?;
        range(
            p.gae_lambda.is_finite() && (0.0..=1.0).contains(&p.gae_lambda),
            "ppo.gae_lambda",
            p.gae_lambda,
            "must be in [0, 1]",
        )?;
        finite_nonneg("ppo.entropy_coef", p.entropy_coef)?;
        finite_nonneg("ppo.value_coef", p.value_coef)?;
        finite_pos("ppo.max_grad_norm", p.max_grad_norm)?;
        range(
            p.log_std_init.is_finite() && (-10.0..=2.0).contains(&p.log_std_init),
            "ppo.log_std_init",
            p.log_std_init,
            "must be in [-10, 2]",
        )?;
        Ok(())
    }
}

impl SacConfig {
    pub(super) fn check(&self) -> Result<(), ConfigError> {
        let c = self;
        range(
            !c.hidden.is_empty() && !c.hidden.contains(&0),
            "sac.hidden",
            format!("{:?}", c.hidden),
            "must list >= 1 width, all > 0",
        )?;
        finite_pos("sac.lr", c.lr)?;
        range(c.batch >= 1, "sac.batch", c.batch, "must be >= 1")?;
        range(
            c.buffer >= c.batch,
            "sac.buffer",
            c.buffer,
            "must be >= sac.batch",
        )?;
        range(
            c.gamma.is_finite() && c.gamma > 0.0 && c.gamma < 1.0,
            "sac.gamma",
            c.gamma,
            "must be in (0, 1)",
        )?;
        range(
            c.tau.is_finite() && c.tau > 0.0 && c.tau <= 1.0,
            "sac.tau",
            c.tau,
            "must be in (0, 1]",
        )?;
        range(
            c.updates_per_step >= 1,
            "sac.updates_per_step",
            c.updates_per_step,
            "must be >= 1",
        )?;
        finite_pos("sac.init_alpha", c.init_alpha)?;
        range(
            c.target_entropy_per_dim.is_finite(),
            "sac.target_entropy_per_dim",
            c.target_entropy_per_dim,
            "must be finite",
        )?;
        range(
            c.log_every >= 1,
            "sac.log_every",
            c.log_every,
            "must be >= 1",
        )?;
        Ok(())
    }
}

impl DiscConfig {
    pub(super) fn check(&self) -> Result<(), ConfigError> {
        let q = self;
        range(
            !q.hidden.is_empty() && !q.hidden.contains(&0),
            "disc.hidden",
            format!("{:?}", q.hidden),
            "must list >= 1 width, all > 0",
        )?;
        finite_pos("disc.lr", q.lr)?;
        range(q.batch >= 2, "disc.batch", q.batch, "must be >= 2")?;
        for (k, v) in [
            ("disc.label_smoothing", q.label_smoothing),
            ("disc.label_smoothing_policy", q.label_smoothing_policy),
        ] {
            range((0.0..0.5).contains(&v), k, v, "must be in [0, 0.5)")?;
        }
        finite_nonneg("disc.input_noise", q.input_noise)?;
        Ok(())
    }
}

impl RunConfig {
    pub(super) fn check(&self) -> Result<(), ConfigError> {
        let r = self;
        range(
            r.iterations >= 1,
            "run.iterations",
            r.iterations,
            "must be >= 1",
        )?;
        range(
            r.rollout_steps >= 1,
            "run.rollout_steps",
            r.rollout_steps,
            "must be >= 1",
        )?;
        range(
            r.actors <= 256,
            "run.actors",
            r.actors,
            "must be in 0..=256 (0: one actor thread in the learner)",
        )?;
        range(
            r.actor_timeout_s.is_finite() && (0.5..=3600.0).contains(&r.actor_timeout_s),
            "run.actor_timeout_s",
            r.actor_timeout_s,
            "must be in 0.5..=3600",
        )?;
        range(
            r.torch_threads <= 1024,
            "run.torch_threads",
            r.torch_threads,
            "must be <= 1024",
        )?;
        range(
            r.eval_episodes >= 1,
            "run.eval_episodes",
            r.eval_episodes,
            "must be >= 1",
        )?;
        range(
            r.eval_episodes_periodic >= 1,
            "run.eval_episodes_periodic",
            r.eval_episodes_periodic,
            "must be >= 1",
        )?;
        range(
            (1..=100_000).contains(&r.log_chunk_steps),
            "run.log_chunk_steps",
            r.log_chunk_steps,
            "must be in 1..=100000",
        )?;
        Ok(())
    }
}
