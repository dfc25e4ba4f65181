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

use crate::humanoid::{Humanoid, HumanoidConfig};
use crate::locomotion::check_n_modes;
use crate::pusher::{Pusher, PusherConfig};
use crate::reacher::{Reacher, ReacherConfig};
use crate::traj2d::{Traj2D, Traj2DConfig};
use crate::walker2d::{Walker2d, Walker2dConfig};

/// Names of every environment: all are built by [`make_plain_env`] and by [`make_env`]
/// (traj2d and reacher with scripted experts, the others with trained ones).
pub const KNOWN_ENVS: &[&str] = &["traj2d", "reacher", "pusher", "walker2d", "humanoid"];

/// Static description of an environment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EnvSpec {
    /// Environment name, as accepted by [`make_env`].
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
    /// [`make_env`] was given an unknown name.
    #[error("unknown environment {name:?}; known environments: {known}")]
    UnknownEnv {
        /// Name requested.
        name: String,
        /// Comma-separated list of known names.
        known: String,
    },
    /// [`make_env`] was asked for a known env that has no scripted expert; build it
    /// with [`make_plain_env`] instead.
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

/// Builds an env with an expert for every mode by name: `"traj2d"` and `"reacher"` have
/// scripted experts; the others are driven by their trained experts from
/// [`crate::experts_dir`] ([`crate::ExpertEnv`]). `n_modes` is the requested number of
/// behaviour modes: traj2d supports exactly 4, reacher 2 to 12 (targets); anything else
/// is [`EnvError::BadParam`] naming `n_modes`. Missing or unfit expert files are
/// [`EnvError::NoScriptedExpert`] naming the file; an unknown name is
/// [`EnvError::UnknownEnv`], listing the known ones.
pub fn make_env(name: &str, n_modes: usize) -> Result<Box<dyn ScriptedExpert>, EnvError> {
    make_env_in(name, n_modes, &crate::experts_dir())
}

/// [`make_env`] with trained experts looked up under `experts_dir`.
pub fn make_env_in(
    name: &str,
    n_modes: usize,
    experts_dir: &std::path::Path,
) -> Result<Box<dyn ScriptedExpert>, EnvError> {
    if crate::task::task_path(name).is_some() {
        return Err(EnvError::NoScriptedExpert {
            name: name.to_owned(),
            reason: "a task file has no expert; train it from imported demonstrations \
                     (`demos.path`, see `ess demos import`)"
                .into(),
        });
    }
    match name {
        "pusher" | "walker2d" | "humanoid" => {
            let plain = make_plain_env(name, n_modes)?;
            let env = crate::ExpertEnv::load(plain, experts_dir).map_err(|e| {
                EnvError::NoScriptedExpert {
                    name: name.to_owned(),
                    reason: e.to_string(),
                }
            })?;
            Ok(Box::new(env))
        }
        "traj2d" => {
            if n_modes != Traj2D::N_MODES {
                return Err(EnvError::BadParam {
                    field: "n_modes",
                    value: n_modes.to_string(),
                    reason: format!("traj2d has exactly {} modes", Traj2D::N_MODES),
                });
            }
            Ok(Box::new(Traj2D::new(Traj2DConfig::default())?))
        }
        "reacher" => Ok(Box::new(Reacher::new(ReacherConfig {
            n_modes,
            ..ReacherConfig::default()
        })?)),
        _ => Err(EnvError::UnknownEnv {
            name: name.to_owned(),
            known: KNOWN_ENVS.join(", "),
        }),
    }
}

/// The env as training, its actors and replay step it: a built-in env as [`make_env`]
/// builds it (with its experts, whose wrapper's state differs from the plain env's), a
/// task file (`task:PATH`, [`crate::task`]) as a plain env, since it has no expert.
pub fn make_training_env(name: &str, n_modes: usize) -> Result<Box<dyn Env>, EnvError> {
    if crate::task::task_path(name).is_some() {
        make_plain_env(name, n_modes)
    } else {
        Ok(make_env(name, n_modes)?)
    }
}

/// Builds any known env by name as a plain [`Env`] (no expert), with its default
/// configuration, or a user's task file named `task:PATH` ([`crate::task`]): traj2d (exactly 4 modes), reacher (2 to 12), pusher (2 to 6 goals),
/// walker2d and humanoid (exactly 3: forward, backward, balance). A bad `n_modes` is
/// [`EnvError::BadParam`] naming it; an unknown name is [`EnvError::UnknownEnv`].
pub fn make_plain_env(name: &str, n_modes: usize) -> Result<Box<dyn Env>, EnvError> {
    if let Some(path) = crate::task::task_path(name) {
        return Ok(Box::new(crate::task::TaskEnv::load(path, n_modes)?));
    }
    match name {
        "pusher" => Ok(Box::new(Pusher::new(PusherConfig {
            n_modes,
            ..PusherConfig::default()
        })?)),
        "walker2d" => {
            check_n_modes(name, n_modes)?;
            Ok(Box::new(Walker2d::new(Walker2dConfig::default())?))
        }
        "humanoid" => {
            check_n_modes(name, n_modes)?;
            Ok(Box::new(Humanoid::new(HumanoidConfig::default())?))
        }
        _ => {
            let env: Box<dyn Env> = make_env(name, n_modes)?;
            Ok(env)
        }
    }
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

#[cfg(test)]
pub(crate) mod conformance;

#[cfg(test)]
mod tests {
    use super::conformance::check_env;
    use super::*;
    use rand::SeedableRng;

    /// Every (name, n_modes) built through `make_env` that the suite runs against.
    const ALL_ENVS: &[(&str, usize)] = &[
        ("traj2d", 4),
        ("reacher", 2),
        ("reacher", 6),
        ("pusher", 6),
        ("walker2d", 3),
        ("humanoid", 3),
    ];

    #[test]
    fn every_make_env_env_passes_the_conformance_suite() {
        for &(name, k) in ALL_ENVS {
            check_env(name, &|| {
                let env: Box<dyn Env> = make_env(name, k).expect("known env builds");
                env
            });
        }
    }

    #[test]
    fn expert_rejects_an_out_of_range_mode() {
        for &(name, k) in ALL_ENVS {
            let mut env = make_env(name, k).expect("env");
            let spec = env.spec().clone();
            let mut obs = vec![0.0; spec.obs_dim];
            env.reset(0, &mut obs).expect("reset");
            let mut rng = ChaCha8Rng::seed_from_u64(0);
            let mut act = vec![0.0; spec.act_dim];
            let err = env.expert_action(k, &mut rng, &mut act).unwrap_err();
            assert!(
                matches!(err, EnvError::ModeOutOfRange { mode, n_modes } if mode == k && n_modes == k),
                "{name}: {err}"
            );
        }
    }

    #[test]
    fn make_env_lists_known_envs_for_an_unknown_name() {
        let err = make_env("cartpole", 2).err().expect("unknown env");
        let msg = err.to_string();
        assert!(msg.contains("cartpole") && msg.contains("traj2d"), "{msg}");
    }

    #[test]
    fn make_env_rejects_an_unsupported_mode_count() {
        let err = make_env("traj2d", 6).err().expect("bad n_modes");
        assert!(
            matches!(
                err,
                EnvError::BadParam {
                    field: "n_modes",
                    ..
                }
            ),
            "{err}"
        );
        assert!(err.to_string().contains("n_modes = 6"), "{err}");
        for k in [1, 13] {
            let err = make_env("reacher", k).err().expect("bad n_modes");
            assert!(err.to_string().contains(&format!("n_modes = {k}")), "{err}");
        }
    }

    #[test]
    fn make_plain_env_builds_every_known_env() {
        for (name, k) in [
            ("traj2d", 4),
            ("reacher", 6),
            ("walker2d", 3),
            ("humanoid", 3),
        ] {
            let env = make_plain_env(name, k).expect(name);
            assert_eq!((env.spec().name.as_str(), env.spec().n_modes), (name, k));
            assert!(KNOWN_ENVS.contains(&name), "{name}");
        }
        let err = make_plain_env("cartpole", 3).err().expect("unknown env");
        assert!(matches!(err, EnvError::UnknownEnv { .. }), "{err}");
    }

    #[test]
    fn make_plain_env_rejects_a_locomotion_mode_count_other_than_three() {
        for k in [0, 2, 4] {
            for name in ["walker2d", "humanoid"] {
                let err = make_plain_env(name, k).err().expect("bad n_modes");
                assert!(
                    matches!(
                        err,
                        EnvError::BadParam {
                            field: "n_modes",
                            ..
                        }
                    ),
                    "{err}"
                );
                assert!(err.to_string().contains(&format!("n_modes = {k}")), "{err}");
            }
        }
    }

    #[test]
    fn make_env_builds_reacher_with_the_requested_number_of_targets() {
        for k in 2..=12 {
            let env = make_env("reacher", k).expect("reacher");
            assert_eq!(env.spec().n_modes, k);
            assert_eq!(env.spec().name, "reacher");
        }
    }

    #[test]
    fn make_env_without_trained_experts_names_the_missing_file() {
        let dir = tempfile::tempdir().expect("tmp");
        for (env, k) in [("pusher", 6), ("walker2d", 3), ("humanoid", 3)] {
            let err = make_env_in(env, k, dir.path()).err().expect("no expert");
            assert!(
                matches!(&err, EnvError::NoScriptedExpert { name, .. } if name == env),
                "{err}"
            );
            let msg = err.to_string();
            assert!(
                msg.contains("mode0.safetensors")
                    && msg.contains(&format!("ess experts train --env {env}")),
                "{msg}"
            );
        }
    }

    #[test]
    fn make_plain_env_builds_every_known_env_including_pusher() {
        for (name, k) in [("traj2d", 4), ("reacher", 6), ("pusher", 6), ("pusher", 2)] {
            assert!(KNOWN_ENVS.contains(&name));
            let env = make_plain_env(name, k).expect("known env builds");
            assert_eq!((env.spec().name.as_str(), env.spec().n_modes), (name, k));
        }
        check_env("pusher via make_plain_env", &|| {
            make_plain_env("pusher", 6).expect("pusher")
        });
    }

    #[test]
    fn make_plain_env_validates_names_and_mode_counts() {
        for k in [1, 7] {
            let err = make_plain_env("pusher", k).err().expect("bad n_modes");
            assert!(
                matches!(
                    err,
                    EnvError::BadParam {
                        field: "n_modes",
                        ..
                    }
                ),
                "{err}"
            );
        }
        let err = make_plain_env("traj2d", 6).err().expect("bad n_modes");
        assert!(err.to_string().contains("n_modes = 6"), "{err}");
        let err = make_plain_env("cartpole", 2).err().expect("unknown env");
        assert!(matches!(err, EnvError::UnknownEnv { .. }), "{err}");
        assert!(err.to_string().contains("pusher"), "{err}");
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
