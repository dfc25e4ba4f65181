//! A chunk of transitions produced by one actor under one policy version.
//!
//! Arrays are row-major, one row per step. The learner needs the Gumbel noise `gumbel`
//! each step's code was drawn with, so that it can recompute
//! `c = softmax((log p(c) + g) / tau)` (Eq. 7) and differentiate through it.

/// Transitions of consecutive steps from one or more episodes.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Chunk {
    /// Version of the policy weights that produced every step.
    pub policy_version: u64,
    /// Observation width.
    pub obs_dim: usize,
    /// Action width.
    pub act_dim: usize,
    /// Number of latent codes `K`.
    pub n_codes: usize,
    /// `[len][obs_dim]` observation before the step.
    pub obs: Vec<f32>,
    /// `[len][obs_dim]` observation after the step.
    pub next_obs: Vec<f32>,
    /// `[len][act_dim]` Gaussian sample before the tanh squashing.
    pub pre_tanh: Vec<f32>,
    /// `[len][act_dim]` action sent to the environment, `tanh(pre_tanh)`.
    pub act: Vec<f32>,
    /// `[len]` Gaussian log-density of `pre_tanh` under the acting policy.
    pub logp: Vec<f32>,
    /// `[len][n_codes]` soft latent skill `c` fed to the policy.
    pub code: Vec<f32>,
    /// `[len][n_codes]` Gumbel(0, 1) noise `c` was drawn with.
    pub gumbel: Vec<f32>,
    /// `[len]` latent shifting variable `eps ~ U(-1, 1)`.
    pub eps: Vec<f32>,
    /// `[len]` the episode ended in a terminal state after this step.
    pub terminated: Vec<bool>,
    /// `[len]` the episode was cut (time limit) after this step.
    pub truncated: Vec<bool>,
    /// `[len]` environment task reward for the episode's true mode, if the env has one
    /// (a tiny optional term of the policy reward; 0 otherwise).
    pub env_reward: Vec<f32>,
}

impl Chunk {
    /// An empty chunk with room for `cap` steps.
    pub fn with_capacity(obs_dim: usize, act_dim: usize, n_codes: usize, cap: usize) -> Self {
        Self {
            policy_version: 0,
            obs_dim,
            act_dim,
            n_codes,
            obs: Vec::with_capacity(cap * obs_dim),
            next_obs: Vec::with_capacity(cap * obs_dim),
            pre_tanh: Vec::with_capacity(cap * act_dim),
            act: Vec::with_capacity(cap * act_dim),
            logp: Vec::with_capacity(cap),
            code: Vec::with_capacity(cap * n_codes),
            gumbel: Vec::with_capacity(cap * n_codes),
            eps: Vec::with_capacity(cap),
            terminated: Vec::with_capacity(cap),
            truncated: Vec::with_capacity(cap),
            env_reward: Vec::with_capacity(cap),
        }
    }

    /// Number of steps.
    pub fn len(&self) -> usize {
        self.logp.len()
    }

    /// True when the chunk holds no step.
    pub fn is_empty(&self) -> bool {
        self.logp.is_empty()
    }

    /// Appends all steps of `other` (same dims) to `self`.
    pub fn extend(&mut self, other: &Chunk) {
        self.obs.extend_from_slice(&other.obs);
        self.next_obs.extend_from_slice(&other.next_obs);
        self.pre_tanh.extend_from_slice(&other.pre_tanh);
        self.act.extend_from_slice(&other.act);
        self.logp.extend_from_slice(&other.logp);
        self.code.extend_from_slice(&other.code);
        self.gumbel.extend_from_slice(&other.gumbel);
        self.eps.extend_from_slice(&other.eps);
        self.terminated.extend_from_slice(&other.terminated);
        self.truncated.extend_from_slice(&other.truncated);
        self.env_reward.extend_from_slice(&other.env_reward);
    }
}

/// One transition, borrowed: what a rollout loop hands a [`StepSink`].
#[derive(Debug, Clone, Copy)]
pub struct Step<'a> {
    /// `[obs_dim]` observation before the step.
    pub obs: &'a [f32],
    /// `[obs_dim]` observation after the step.
    pub next_obs: &'a [f32],
    /// `[act_dim]` Gaussian sample before tanh.
    pub pre_tanh: &'a [f32],
    /// `[act_dim]` action sent.
    pub act: &'a [f32],
    /// Gaussian log-density of `pre_tanh`.
    pub logp: f32,
    /// `[n_codes]` soft latent code.
    pub code: &'a [f32],
    /// `[n_codes]` Gumbel noise.
    pub gumbel: &'a [f32],
    /// Shifting variable.
    pub eps: f32,
    /// Terminal state after the step.
    pub terminated: bool,
    /// Time limit after the step.
    pub truncated: bool,
    /// Task reward.
    pub env_reward: f32,
}

/// Where a rollout loop puts its steps: an owned [`Chunk`], or a shared-memory sample
/// ([`crate::shm::ShmChunkWriter`]) written in place.
pub trait StepSink {
    /// Why a push failed.
    type Error;
    /// Appends one step.
    fn push(&mut self, s: &Step<'_>) -> Result<(), Self::Error>;
}

impl StepSink for Chunk {
    type Error = std::convert::Infallible;
    fn push(&mut self, s: &Step<'_>) -> Result<(), Self::Error> {
        self.obs.extend_from_slice(s.obs);
        self.next_obs.extend_from_slice(s.next_obs);
        self.pre_tanh.extend_from_slice(s.pre_tanh);
        self.act.extend_from_slice(s.act);
        self.logp.push(s.logp);
        self.code.extend_from_slice(s.code);
        self.gumbel.extend_from_slice(s.gumbel);
        self.eps.push(s.eps);
        self.terminated.push(s.terminated);
        self.truncated.push(s.truncated);
        self.env_reward.push(s.env_reward);
        Ok(())
    }
}
