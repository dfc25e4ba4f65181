//! The environment contract shared by every Ess environment.
//!
//! An [`Env`] is a single episodic simulator with a fixed [`EnvSpec`]: observations of
//! `obs_dim` floats, actions of `act_dim` floats in `[-1, 1]`, and `n_modes` behaviour
//! modes, each with its own *evaluation* reward ([`Env::mode_rewards`]) that only the
//! evaluation code reads — the imitation policy never sees it.
//!
//! Buffers are caller-owned (`&mut [f32]`) so actors can step thousands of envs without
//! allocating. Every method checks buffer lengths and returns an [`EnvError`] naming
//! the offending value instead of panicking.
//!
//! A [`ScriptedExpert`] env additionally provides a stochastic expert per behaviour
//! mode; demonstration datasets ([`crate::demos`]) are rolled from it.

use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Static description of an environment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EnvSpec {
    /// Environment name, as accepted by [`crate::make_env`].
    pub name: String,
    /// Length of an observation vector.
    pub obs_dim: usize,
    /// Length of an action vector; every component lies in `[-1, 1]`.
    pub act_dim: usize,
    /// Number of behaviour modes (length of [`Env::mode_rewards`]'s output).
    pub n_modes: usize,
    /// Episode length limit; the step that reaches it reports `truncated`.
    pub max_steps: usize,
}

/// How an episode stands after a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StepOutcome {
    /// The episode reached a terminal state (no bootstrapping past it).
    pub terminated: bool,
    /// The episode was cut by the time limit (bootstrapping past it is valid).
    pub truncated: bool,
}

impl StepOutcome {
    /// True when the episode is over, for either reason.
    pub fn done(&self) -> bool {
        self.terminated || self.truncated
    }
}

/// Errors of environment construction and stepping.
#[derive(Debug, thiserror::Error)]
pub enum EnvError {
    /// `step` (or the expert) was called before the first `reset`.
    #[error("the environment was used before reset was called")]
    NotReset,
    /// [`Env::set_state`] got a state vector that does not fit this env.
    #[error("state for env `{env}` is invalid: {why}")]
    BadState {
        /// The env's name.
        env: String,
        /// What does not fit (length, a non-finite value, ...).
        why: String,
    },
    /// `step` was called after the episode had terminated or been truncated.
    #[error("step called after the episode ended (after {steps} steps); call reset first")]
    StepAfterDone {
        /// Steps taken in the finished episode.
        steps: usize,
    },
    /// The action slice has the wrong length.
    #[error("action has length {got}, expected act_dim = {expected}")]
    BadActionLen {
        /// `act_dim` of the env.
        expected: usize,
        /// Length received.
        got: usize,
    },
    /// The observation buffer has the wrong length.
    #[error("observation buffer has length {got}, expected obs_dim = {expected}")]
    BadObsLen {
        /// `obs_dim` of the env.
        expected: usize,
        /// Length received.
        got: usize,
    },
    /// An action component is NaN or infinite.
    #[error("action[{index}] = {value} is not finite")]
    NonFiniteAction {
        /// Index of the offending component.
        index: usize,
        /// Its value.
        value: f32,
    },
    /// A behaviour mode index is out of range.
    #[error("mode {mode} is out of range: the env has {n_modes} modes")]
    ModeOutOfRange {
        /// Mode requested.
        mode: usize,
        /// Number of modes of the env.
        n_modes: usize,
    },
    /// [`crate::make_env`] was given an unknown name.
    #[error("unknown environment {name:?}; known environments: {known}")]
    UnknownEnv {
        /// Name requested.
        name: String,
        /// Comma-separated list of known names.
        known: String,
    },
    /// [`crate::make_env`] was asked for a known env that has no scripted expert; build it
    /// with [`crate::make_plain_env`] instead.
    #[error(
        "environment {name:?} has no scripted expert and its trained experts could not be loaded: {reason}"
    )]
    NoScriptedExpert {
        /// Name requested.
        name: String,
        /// Why the trained experts are unavailable (names the file).
        reason: String,
    },
    /// A construction parameter is invalid.
    #[error("invalid parameter {field} = {value}: {reason}")]
    BadParam {
        /// Name of the field.
        field: &'static str,
        /// Its value, formatted.
        value: String,
        /// Why it is rejected.
        reason: String,
    },
    /// A MuJoCo model (MJCF) failed to load or does not have the shape the env needs.
    #[error("invalid MJCF model: {reason}")]
    Model {
        /// MuJoCo's message, or what the model lacks.
        reason: String,
    },
    /// A task file ([`crate::task`]) is unreadable, malformed or does not fit its model.
    #[error("task file {}: {reason}", path.display())]
    Task {
        /// The task file.
        path: std::path::PathBuf,
        /// What is wrong, naming the key or piece (MuJoCo's message for the MJCF).
        reason: String,
    },
    /// The physics simulation raised a warning (typically a diverging, unstable state).
    #[error("simulation failed: {reason}")]
    Simulation {
        /// What MuJoCo reported.
        reason: String,
    },
}

/// A single episodic environment.
pub trait Env: Send {
    /// Static description: dimensions, number of modes, episode length.
    fn spec(&self) -> &EnvSpec;

    /// Starts an episode; writes the first observation into `obs` (len `obs_dim`).
    /// Deterministic given `seed`.
    fn reset(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), EnvError>;

    /// Applies `action` (len `act_dim`; each component is clamped to `[-1, 1]`) and
    /// writes the next observation into `obs`. Errors with [`EnvError::StepAfterDone`]
    /// once the episode has terminated or been truncated.
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<StepOutcome, EnvError>;

    /// Evaluation reward of the last transition for each behaviour mode, written into
    /// `out` (len `n_modes`; a shorter `out` receives the first modes only). The
    /// imitation policy never sees it. Before the first step of an episode it scores
    /// the start state.
    fn mode_rewards(&self, out: &mut [f32]);

    /// Task reward of the last transition for each behaviour mode (the reward an
    /// expert of that mode is trained on), written like [`Env::mode_rewards`]. The
    /// default is the evaluation reward; an env overrides it where training needs
    /// shaping that scoring must not see.
    fn task_rewards(&self, out: &mut [f32]) {
        self.mode_rewards(out);
    }

    /// Mode-agnostic reward of the last transition, the same whatever the mode (the
    /// paper's code calls it `reward_train` and adds it to the imitation reward scaled
    /// by `reward_t_coef`, 0.005). It says nothing about which mode runs: for the
    /// locomotion envs it rewards moving in either direction and staying upright
    /// ([`crate::locomotion`]). The imitation objective adds it with
    /// `method.reward_shared` (0 by default). The default is 0.
    fn shared_reward(&self) -> f32 {
        0.0
    }

    /// Whether [`Env::mode_rewards`] scores the modes (every built-in env does; a task
    /// file only with `[[modes]]`). Without it normalized reward does not apply.
    fn has_mode_rewards(&self) -> bool {
        true
    }

    /// Forward velocity of the body in m/s after the last step, for locomotion envs
    /// (reported per mode by `ess experts eval`); `None` where it has no meaning.
    fn forward_velocity(&self) -> Option<f64> {
        None
    }

    /// The env's bodies and their geoms as a 3D viewer draws them (Foxglove through the
    /// run log); `None` for an env without a body model (Traj2D).
    fn scene(&self) -> Option<crate::scene::Scene> {
        None
    }

    /// Each body's world pose now (after `reset`, `step` or `set_state`), in the order
    /// of [`Env::scene`]'s bodies; empty where `scene` is `None`.
    fn body_poses(&self) -> Vec<crate::scene::Pose> {
        Vec::new()
    }

    /// The env's complete state as a flat vector: the simulator state and every field
    /// the next `step`, `mode_rewards` and `task_rewards` read (episode step count, done
    /// flag, last action, ...). [`Env::set_state`] with it makes the env continue
    /// bit-identically. Used by checkpoints (mid-episode workers) and `ess replay`.
    fn state(&self) -> Vec<f64>;

    /// Restores a vector from [`Env::state`] of an env built with the same name and
    /// parameters; [`EnvError::BadState`] when its length or contents do not fit.
    fn set_state(&mut self, state: &[f64]) -> Result<(), EnvError>;
}

/// An env whose behaviour modes have a scripted (stochastic) expert.
pub trait ScriptedExpert: Env {
    /// Expert action for `mode` in the current state, written into `action`
    /// (len `act_dim`); stochastic through `rng`.
    fn expert_action(
        &self,
        mode: usize,
        rng: &mut ChaCha8Rng,
        action: &mut [f32],
    ) -> Result<(), EnvError>;
}

/// How [`crate::registry`] builds one env from a mode count (each checks its own
/// `n_modes`, [`EnvError::BadParam`] naming it).
#[derive(Clone, Copy)]
pub enum Build {
    /// The env has scripted experts; as a plain env it is the same object.
    Scripted(fn(usize) -> Result<Box<dyn ScriptedExpert>, EnvError>),
    /// A plain env whose experts are trained policies from the experts folder
    /// ([`crate::ExpertEnv`]).
    Trained(fn(usize) -> Result<Box<dyn Env>, EnvError>),
}

/// One line of the env registry: an env file's name and constructor.
#[derive(Clone, Copy)]
pub struct EnvEntry {
    /// The name `--env` takes.
    pub name: &'static str,
    /// How it is built.
    pub build: Build,
}

/// Checks that `buf` has length `expected`, as an observation buffer.
pub(crate) fn check_obs_len(buf: &[f32], expected: usize) -> Result<(), EnvError> {
    if buf.len() == expected {
        Ok(())
    } else {
        Err(EnvError::BadObsLen {
            expected,
            got: buf.len(),
        })
    }
}

/// Checks that an episode may step: it was `started` by a reset and is not `done`
/// (`steps` taken so far go into the error).
pub(crate) fn check_can_step(started: bool, done: bool, steps: usize) -> Result<(), EnvError> {
    if !started {
        return Err(EnvError::NotReset);
    }
    if done {
        return Err(EnvError::StepAfterDone { steps });
    }
    Ok(())
}

/// Checks that `action` has length `expected` and only finite components.
pub(crate) fn check_action(action: &[f32], expected: usize) -> Result<(), EnvError> {
    if action.len() != expected {
        return Err(EnvError::BadActionLen {
            expected,
            got: action.len(),
        });
    }
    match action.iter().position(|a| !a.is_finite()) {
        Some(index) => Err(EnvError::NonFiniteAction {
            index,
            value: action[index],
        }),
        None => Ok(()),
    }
}

/// Builds the flat vector of [`Env::state`]: scalars, counters and flags in a fixed order.
#[derive(Debug, Default)]
pub(crate) struct StateWriter(Vec<f64>);

impl StateWriter {
    /// Appends values.
    pub fn put(&mut self, values: &[f64]) -> &mut Self {
        self.0.extend_from_slice(values);
        self
    }

    /// Appends a counter (exact below 2^53).
    pub fn count(&mut self, n: usize) -> &mut Self {
        self.0.push(n as f64);
        self
    }

    /// Appends a flag as 0 or 1.
    pub fn flag(&mut self, b: bool) -> &mut Self {
        self.0.push(f64::from(u8::from(b)));
        self
    }

    /// The vector.
    pub fn finish(&mut self) -> Vec<f64> {
        std::mem::take(&mut self.0)
    }
}

/// Reads a vector written by [`StateWriter`] in the same order; every misfit is
/// [`EnvError::BadState`] naming the env.
#[derive(Debug)]
pub(crate) struct StateReader<'a> {
    env: &'a str,
    data: &'a [f64],
    at: usize,
}

impl<'a> StateReader<'a> {
    /// Checks that `data` has exactly `len` values, all finite.
    pub fn new(env: &'a str, data: &'a [f64], len: usize) -> Result<Self, EnvError> {
        let bad = |why: String| EnvError::BadState {
            env: env.to_owned(),
            why,
        };
        if data.len() != len {
            return Err(bad(format!("has {} values, expected {len}", data.len())));
        }
        if let Some(i) = data.iter().position(|x| !x.is_finite()) {
            return Err(bad(format!("value {i} is {} (not finite)", data[i])));
        }
        Ok(Self { env, data, at: 0 })
    }

    fn bad(&self, why: String) -> EnvError {
        EnvError::BadState {
            env: self.env.to_owned(),
            why,
        }
    }

    /// The next `n` values.
    pub fn take(&mut self, n: usize) -> &'a [f64] {
        let s = &self.data[self.at..self.at + n];
        self.at += n;
        s
    }

    /// The next value.
    pub fn scalar(&mut self) -> f64 {
        self.take(1)[0]
    }

    /// The next counter: a whole number in `0..=max`.
    pub fn count(&mut self, what: &str, max: usize) -> Result<usize, EnvError> {
        let at = self.at;
        let x = self.scalar();
        if x < 0.0 || x.fract() != 0.0 || x > max as f64 {
            return Err(self.bad(format!(
                "value {at} ({what}) is {x}, expected a whole number in 0..={max}"
            )));
        }
        Ok(x as usize)
    }

    /// The next flag (0 or 1).
    pub fn flag(&mut self, what: &str) -> Result<bool, EnvError> {
        let at = self.at;
        match self.scalar() {
            0.0 => Ok(false),
            1.0 => Ok(true),
            x => Err(self.bad(format!("value {at} ({what}) is {x}, expected 0 or 1"))),
        }
    }
}

#[cfg(test)]
pub(crate) mod conformance;
