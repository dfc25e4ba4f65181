//! Rollout workers: step one environment with the acting policy into [`Chunk`]s, and run
//! deterministic evaluation episodes with a given one-hot code.
//!
//! A worker keeps its episode across calls: a chunk ends after exactly the steps asked
//! for, possibly mid-episode; the learner bootstraps the value at a chunk's last step.

use crate::policy::{Actor, LatentSpec, PolicyWeights};
use ess_envs::{Env, EnvError};
use ess_proto::shm::ShmError;
use ess_proto::{Chunk, Step, StepSink};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Errors while acting.
#[derive(Debug, thiserror::Error)]
pub enum ActorError {
    /// The environment refused a call.
    #[error("environment error: {0}")]
    Env(#[from] EnvError),
    /// Weights that do not fit the environment.
    #[error("policy weights do not fit env `{env}`: {what}")]
    Mismatch {
        /// The env's name.
        env: String,
        /// What does not fit.
        what: String,
    },
    /// A shared-memory buffer was refused.
    #[error("shared memory: {0}")]
    Shm(#[from] ShmError),
    /// The transport between learner and actor processes failed.
    #[error("actor transport: {what}")]
    Transport {
        /// What failed.
        what: String,
    },
    /// A worker thread is gone.
    #[error("actor worker {index} stopped: {why}")]
    WorkerGone {
        /// Worker index.
        index: usize,
        /// Why.
        why: String,
    },
}

impl From<std::convert::Infallible> for ActorError {
    fn from(e: std::convert::Infallible) -> Self {
        match e {}
    }
}

/// Checks that `w` fits an env of `obs_dim`/`act_dim` and `n_codes` codes.
pub fn check_fit(env: &dyn Env, w: &PolicyWeights, latent: &LatentSpec) -> Result<(), ActorError> {
    let s = env.spec();
    let want_in = s.obs_dim + 1 + latent.n_codes;
    let mismatch = |what: String| ActorError::Mismatch {
        env: s.name.clone(),
        what,
    };
    if w.mean.layout().input() != want_in {
        return Err(mismatch(format!(
            "policy input is {}, expected obs {} + eps 1 + codes {}",
            w.mean.layout().input(),
            s.obs_dim,
            latent.n_codes
        )));
    }
    if w.mean.layout().output() != s.act_dim || w.log_std.len() != s.act_dim {
        return Err(mismatch(format!(
            "policy output {} / log_std {}, expected act_dim {}",
            w.mean.layout().output(),
            w.log_std.len(),
            s.act_dim
        )));
    }
    if w.obs_mean.len() != s.obs_dim || w.obs_std.len() != s.obs_dim {
        return Err(mismatch("observation normaliser size".into()));
    }
    if w.prior_logits.len() != latent.n_codes {
        return Err(mismatch(format!(
            "{} prior logits for {} codes",
            w.prior_logits.len(),
            latent.n_codes
        )));
    }
    Ok(())
}

/// Everything a [`Worker`] carries from one step to the next: restored into a worker
/// over an env of the same kind ([`Worker::restore`]), it continues bit-identically,
/// mid-episode included.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkerState {
    /// Seed of the ChaCha8 stream.
    pub rng_seed: [u8; 32],
    /// Stream number of the ChaCha8 generator.
    pub rng_stream: u64,
    /// Word position of the ChaCha8 generator.
    pub rng_word_pos: u128,
    /// Observation the next step acts on.
    pub obs: Vec<f32>,
    /// Latent code of the current episode.
    pub code: Vec<f32>,
    /// Gumbel noise the code was drawn with.
    pub gumbel: Vec<f32>,
    /// Latent noise eps of the current episode.
    pub eps: f32,
    /// Whether an episode is under way (else the next step resets).
    pub in_episode: bool,
    /// [`Env::state`].
    pub env: Vec<f64>,
}

/// One environment with its episode state and random stream.
pub struct Worker {
    env: Box<dyn Env>,
    rng: ChaCha8Rng,
    obs: Vec<f32>,
    next: Vec<f32>,
    code: Vec<f32>,
    gumbel: Vec<f32>,
    eps: f32,
    pre: Vec<f32>,
    act: Vec<f32>,
    in_episode: bool,
    /// Mode whose task reward goes into `Chunk::env_reward` (expert training), if any.
    task_mode: Option<usize>,
    task_rewards: Vec<f32>,
}

impl Worker {
    /// A worker over `env`, its randomness seeded by `seed`.
    pub fn new(env: Box<dyn Env>, seed: u64, n_codes: usize) -> Self {
        let s = env.spec().clone();
        Self {
            env,
            rng: ChaCha8Rng::seed_from_u64(seed),
            obs: vec![0.0; s.obs_dim],
            next: vec![0.0; s.obs_dim],
            code: vec![0.0; n_codes],
            gumbel: vec![0.0; n_codes],
            eps: 0.0,
            pre: vec![0.0; s.act_dim],
            act: vec![0.0; s.act_dim],
            in_episode: false,
            task_mode: None,
            task_rewards: vec![0.0; s.n_modes],
        }
    }

    /// Records the task reward of `mode` ([`Env::task_rewards`]) as each step's
    /// `env_reward` (expert training); without it `env_reward` is the env's mode-agnostic
    /// [`Env::shared_reward`] (imitation, `method.reward_shared`). A mode out of range
    /// is [`EnvError::ModeOutOfRange`].
    pub fn with_task_reward(mut self, mode: usize) -> Result<Self, ActorError> {
        let n_modes = self.env.spec().n_modes;
        if mode >= n_modes {
            return Err(EnvError::ModeOutOfRange { mode, n_modes }.into());
        }
        self.task_mode = Some(mode);
        Ok(self)
    }

    /// The environment.
    pub fn env(&self) -> &dyn Env {
        self.env.as_ref()
    }

    /// The worker's complete state between two steps.
    pub fn snapshot(&self) -> WorkerState {
        WorkerState {
            rng_seed: self.rng.get_seed(),
            rng_stream: self.rng.get_stream(),
            rng_word_pos: self.rng.get_word_pos(),
            obs: self.obs.clone(),
            code: self.code.clone(),
            gumbel: self.gumbel.clone(),
            eps: self.eps,
            in_episode: self.in_episode,
            env: self.env.state(),
        }
    }

    /// Continues from `s` (a [`Worker::snapshot`] of a worker over the same kind of env
    /// with as many codes). A state that does not fit changes nothing.
    pub fn restore(&mut self, s: &WorkerState) -> Result<(), ActorError> {
        let spec = self.env.spec();
        let mismatch = |what: String| ActorError::Mismatch {
            env: spec.name.clone(),
            what,
        };
        if s.obs.len() != self.obs.len() {
            return Err(mismatch(format!(
                "worker state has {} observation values, the env {}",
                s.obs.len(),
                self.obs.len()
            )));
        }
        if s.code.len() != self.code.len() || s.gumbel.len() != self.gumbel.len() {
            return Err(mismatch(format!(
                "worker state has {} code / {} gumbel values for {} codes",
                s.code.len(),
                s.gumbel.len(),
                self.code.len()
            )));
        }
        self.env.set_state(&s.env)?;
        let mut rng = ChaCha8Rng::from_seed(s.rng_seed);
        rng.set_stream(s.rng_stream);
        rng.set_word_pos(s.rng_word_pos);
        self.rng = rng;
        self.obs.copy_from_slice(&s.obs);
        self.code.copy_from_slice(&s.code);
        self.gumbel.copy_from_slice(&s.gumbel);
        self.eps = s.eps;
        self.in_episode = s.in_episode;
        Ok(())
    }

    /// Steps `n` times under `w`, starting new episodes (and drawing new latents) as needed.
    pub fn collect(
        &mut self,
        w: &PolicyWeights,
        latent: &LatentSpec,
        n: usize,
    ) -> Result<Chunk, ActorError> {
        check_fit(self.env.as_ref(), w, latent)?;
        let s = self.env.spec();
        let mut chunk = Chunk::with_capacity(s.obs_dim, s.act_dim, latent.n_codes, n);
        chunk.policy_version = w.version;
        self.collect_into(w, latent, n, &mut chunk)?;
        Ok(chunk)
    }

    /// [`Worker::collect`] into any [`StepSink`]: an actor process writes the steps
    /// straight into a loaned shared-memory sample. Same random stream, same steps.
    pub fn collect_into<S>(
        &mut self,
        w: &PolicyWeights,
        latent: &LatentSpec,
        n: usize,
        sink: &mut S,
    ) -> Result<(), ActorError>
    where
        S: StepSink,
        ActorError: From<S::Error>,
    {
        check_fit(self.env.as_ref(), w, latent)?;
        let mut actor = Actor::new(w);
        for _ in 0..n {
            if !self.in_episode {
                let seed = self.rng.random();
                self.env.reset(seed, &mut self.obs)?;
                latent.sample_code(
                    &w.prior_logits,
                    &mut self.rng,
                    &mut self.code,
                    &mut self.gumbel,
                );
                self.eps = latent.sample_eps(&mut self.rng);
                self.in_episode = true;
            }
            let logp = actor.sample(
                w,
                &self.obs,
                self.eps,
                &self.code,
                &mut self.rng,
                &mut self.pre,
                &mut self.act,
            );
            let out = self.env.step(&self.act, &mut self.next)?;
            let r = match self.task_mode {
                Some(k) => {
                    self.env.task_rewards(&mut self.task_rewards);
                    self.task_rewards[k]
                }
                None => self.env.shared_reward(),
            };
            sink.push(&Step {
                obs: &self.obs,
                next_obs: &self.next,
                pre_tanh: &self.pre,
                act: &self.act,
                logp,
                code: &self.code,
                gumbel: &self.gumbel,
                eps: self.eps,
                terminated: out.terminated,
                truncated: out.truncated,
                env_reward: r,
            })?;
            std::mem::swap(&mut self.obs, &mut self.next);
            if out.terminated || out.truncated {
                self.in_episode = false;
            }
        }
        Ok(())
    }
}

/// One deterministic evaluation episode.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EvalEpisode {
    /// The one-hot code index the policy was given.
    pub code: usize,
    /// The eps the policy was given.
    pub eps: f32,
    /// Seed of the env's `reset`.
    pub reset_seed: u64,
    /// Observation after `reset`.
    pub start_obs: Vec<f32>,
    /// The env's complete state after `reset` ([`Env::state`]).
    pub start_state: Vec<f64>,
    /// `[T][state_dim]` the env's state after each step.
    pub states: Vec<f64>,
    /// Length of one state vector.
    pub state_dim: usize,
    /// `[T][obs_dim]` observations before each step.
    pub obs: Vec<f32>,
    /// `[T][act_dim]` actions.
    pub act: Vec<f32>,
    /// `[T][obs_dim]` observations after each step.
    pub next_obs: Vec<f32>,
    /// Number of behaviour modes of the env.
    pub n_modes: usize,
    /// `[T][n_modes]` evaluation reward of each mode per step.
    pub mode_rewards: Vec<f32>,
}

impl EvalEpisode {
    /// Number of steps.
    pub fn len(&self) -> usize {
        self.mode_rewards
            .len()
            .checked_div(self.n_modes)
            .unwrap_or(0)
    }

    /// True if no step was taken.
    pub fn is_empty(&self) -> bool {
        self.mode_rewards.is_empty()
    }

    /// Return of mode `k` over the episode.
    pub fn mode_return(&self, k: usize) -> f32 {
        self.mode_rewards
            .iter()
            .skip(k)
            .step_by(self.n_modes.max(1))
            .sum()
    }
}

/// Runs one deterministic episode with one-hot code `code` (or zeros for
/// [`ess_proto::config::LatentPrior::None`]) and shifting variable `eps`.
pub fn eval_episode(
    env: &mut dyn Env,
    w: &PolicyWeights,
    latent: &LatentSpec,
    code: usize,
    eps: f32,
    seed: u64,
) -> Result<EvalEpisode, ActorError> {
    check_fit(env, w, latent)?;
    let s = env.spec().clone();
    let mut c = vec![0.0; latent.n_codes];
    if latent.prior != ess_proto::config::LatentPrior::None {
        c[code] = 1.0;
    }
    let eps = if latent.use_eps { eps } else { 0.0 };
    let mut actor = Actor::new(w);
    let mut obs = vec![0.0; s.obs_dim];
    let mut next = vec![0.0; s.obs_dim];
    let mut act = vec![0.0; s.act_dim];
    let mut rew = vec![0.0; s.n_modes];
    let mut ep = EvalEpisode {
        code,
        eps,
        reset_seed: seed,
        n_modes: s.n_modes,
        ..Default::default()
    };
    env.reset(seed, &mut obs)?;
    ep.start_obs = obs.clone();
    ep.start_state = env.state();
    ep.state_dim = ep.start_state.len();
    for _ in 0..s.max_steps {
        actor.act_deterministic(w, &obs, eps, &c, &mut act);
        let out = env.step(&act, &mut next)?;
        env.mode_rewards(&mut rew);
        ep.obs.extend_from_slice(&obs);
        ep.act.extend_from_slice(&act);
        ep.next_obs.extend_from_slice(&next);
        ep.mode_rewards.extend_from_slice(&rew);
        ep.states.extend(env.state());
        std::mem::swap(&mut obs, &mut next);
        if out.terminated || out.truncated {
            break;
        }
    }
    Ok(ep)
}
