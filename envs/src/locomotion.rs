//! What the MuJoCo locomotion envs ([`crate::walker2d`], [`crate::humanoid`]) share:
//! the three behaviour modes of the paper's Walker-2D and Humanoid tasks (Sec. 4,
//! Fig. 4), their per-mode reward, the healthy-range test, and the simulation core
//! (model loading and shape checks, seeded reset noise, action scaling, frame skip,
//! MuJoCo warnings as errors).
//!
//! # Modes and rewards
//!
//! Mode 0 runs forward (+x), mode 1 runs backward (-x), mode 2 balances in place. Each
//! mode's reward is Gymnasium v5's locomotion reward with the forward velocity
//! replaced by a mode velocity `v_k`:
//!
//! `r_k = healthy_reward * [healthy] + forward_weight * v_k - ctrl_cost - contact_cost`
//!
//! with `vx` the x-velocity of the step as v5 computes it (the torso's for Walker2d,
//! the centre of mass's for Humanoid), `v_0 = vx`, `v_1 = -vx` and `v_2 = -|vx|`.
//! `contact_cost` is zero for Walker2d. For Walker2d the same formula is both the
//! evaluation reward ([`Env::mode_rewards`](crate::Env::mode_rewards)) and the task
//! reward experts train on ([`Env::task_rewards`](crate::Env::task_rewards) keeps its
//! default); Humanoid trains its experts with a larger velocity weight
//! ([`crate::humanoid`]'s `task_forward_weight`). Balancing
//! is learnable without shaping, since standing still and upright already maximises
//! it, and `-|vx|` summed over an episode is the distance wandered, so it also
//! penalises drift.
//!
//! The shared reward ([`Env::shared_reward`](crate::Env::shared_reward)) is the paper
//! code's mode-agnostic `reward_train`: `0.6 * forward_weight * |vx| + 0.3 * alive`
//! with `alive` 1 on a healthy step and -100 on the step that falls (the reference
//! scales Humanoid's healthy reward of 5 by 0.2, so `alive` is 1 on both envs). It
//! rewards moving in either direction and punishes falling; it never names a mode.
//!
//! Note that `r_2 <= min(r_0, r_1)` always (with equality to `r_1` when moving
//! forward and to `r_0` when moving backward): the balance reward is only comparable
//! between policies, not between modes.

use mujoco_rs::prelude::{MjModel, MjtObjBase};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::env::{EnvError, StateReader, StateWriter, check_action, check_can_step, check_obs_len};
use crate::mujoco::{self, model_error};

/// The shared reward's `alive` term on the step that falls (the paper's code: -100).
const FALL_PENALTY: f64 = -100.0;

/// Number of behaviour modes of every locomotion env.
pub const N_MODES: usize = 3;

/// A behaviour mode of the locomotion envs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LocoMode {
    /// Mode 0: run in the +x direction.
    Forward,
    /// Mode 1: run in the -x direction.
    Backward,
    /// Mode 2: stay upright in place.
    Balance,
}

impl LocoMode {
    /// Every mode, in mode-index order.
    pub const ALL: [LocoMode; N_MODES] = [LocoMode::Forward, LocoMode::Backward, LocoMode::Balance];

    /// Index of the mode (its position in [`Env::mode_rewards`](crate::Env::mode_rewards)).
    pub fn index(self) -> usize {
        match self {
            LocoMode::Forward => 0,
            LocoMode::Backward => 1,
            LocoMode::Balance => 2,
        }
    }

    /// The mode of index `index`, or `None` when out of range.
    pub fn from_index(index: usize) -> Option<Self> {
        Self::ALL.get(index).copied()
    }

    /// Short lowercase name (`forward`, `backward`, `balance`).
    pub fn name(self) -> &'static str {
        match self {
            LocoMode::Forward => "forward",
            LocoMode::Backward => "backward",
            LocoMode::Balance => "balance",
        }
    }

    /// The mode velocity `v_k` rewarded for an x-velocity `vx`: `vx`, `-vx` or `-|vx|`.
    pub fn velocity(self, vx: f64) -> f64 {
        match self {
            LocoMode::Forward => vx,
            LocoMode::Backward => -vx,
            LocoMode::Balance => -vx.abs(),
        }
    }
}

/// Weights of the per-mode reward that do not depend on the step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RewardWeights {
    /// Reward for every step that ends healthy.
    pub healthy_reward: f64,
    /// Weight of the mode velocity `v_k`.
    pub forward_weight: f64,
}

/// The terms of one transition that the per-mode reward is built from.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RewardTerms {
    /// The state after the step is healthy.
    pub healthy: bool,
    /// x-velocity over the step, in m/s.
    pub x_velocity: f64,
    /// Weighted control cost of the step (already multiplied by its weight).
    pub ctrl_cost: f64,
    /// Weighted, clipped contact cost of the step (zero where the env has none).
    pub contact_cost: f64,
}

impl RewardTerms {
    /// Reward of `mode` for this transition (see the module docs).
    pub fn reward(&self, mode: LocoMode, w: &RewardWeights) -> f64 {
        let healthy = if self.healthy { w.healthy_reward } else { 0.0 };
        healthy + w.forward_weight * mode.velocity(self.x_velocity)
            - self.ctrl_cost
            - self.contact_cost
    }

    /// The mode-agnostic shared reward of this transition (see the module docs).
    pub fn shared(&self, w: &RewardWeights) -> f64 {
        let alive = if self.healthy { 1.0 } else { FALL_PENALTY };
        0.6 * w.forward_weight * self.x_velocity.abs() + 0.3 * alive
    }

    /// Number of values [`RewardTerms::save`] writes.
    pub(crate) const STATE_LEN: usize = 4;

    /// Appends the terms to `w`.
    pub(crate) fn save(&self, w: &mut StateWriter) {
        w.flag(self.healthy)
            .put(&[self.x_velocity, self.ctrl_cost, self.contact_cost]);
    }

    /// Reads terms written by [`RewardTerms::save`].
    pub(crate) fn load(r: &mut StateReader<'_>) -> Result<Self, EnvError> {
        Ok(Self {
            healthy: r.flag("healthy")?,
            x_velocity: r.scalar(),
            ctrl_cost: r.scalar(),
            contact_cost: r.scalar(),
        })
    }

    /// Writes the reward of every mode into `out` (a shorter `out` gets the first modes).
    pub fn write_rewards(&self, w: &RewardWeights, out: &mut [f32]) {
        for (r, mode) in out.iter_mut().zip(LocoMode::ALL) {
            *r = self.reward(mode, w) as f32;
        }
    }
}

/// True when `x` lies strictly inside `(range[0], range[1])`, as Gymnasium's healthy
/// tests are written.
pub fn in_open_range(x: f64, range: [f64; 2]) -> bool {
    range[0] < x && x < range[1]
}

/// `n_modes` must be [`N_MODES`] for a locomotion env called `env`.
pub(crate) fn check_n_modes(env: &str, n_modes: usize) -> Result<(), EnvError> {
    if n_modes == N_MODES {
        Ok(())
    } else {
        Err(EnvError::BadParam {
            field: "n_modes",
            value: n_modes.to_string(),
            reason: format!("{env} has exactly {N_MODES} modes (forward, backward, balance)"),
        })
    }
}

/// A config field that must be at least 1.
pub(crate) fn check_positive(field: &'static str, value: usize) -> Result<(), EnvError> {
    if value == 0 {
        return Err(EnvError::BadParam {
            field,
            value: "0".into(),
            reason: "must be at least 1".into(),
        });
    }
    Ok(())
}

/// A config field that must be finite and non-negative.
pub(crate) fn check_non_negative(field: &'static str, value: f64) -> Result<(), EnvError> {
    if !(value.is_finite() && value >= 0.0) {
        return Err(EnvError::BadParam {
            field,
            value: value.to_string(),
            reason: "must be non-negative and finite".into(),
        });
    }
    Ok(())
}

/// A config field holding a range `[lo, hi]` with `lo < hi`, both finite.
pub(crate) fn check_range(field: &'static str, range: [f64; 2]) -> Result<(), EnvError> {
    if !(range[0].is_finite() && range[1].is_finite() && range[0] < range[1]) {
        return Err(EnvError::BadParam {
            field,
            value: format!("[{}, {}]", range[0], range[1]),
            reason: "must be a finite range [lo, hi] with lo < hi".into(),
        });
    }
    Ok(())
}

/// The shape a locomotion model must have.
pub(crate) struct ModelShape<'a> {
    /// Env name, for messages.
    pub env: &'a str,
    /// Position coordinates.
    pub nq: usize,
    /// Degrees of freedom.
    pub nv: usize,
    /// Actuators.
    pub nu: usize,
    /// Bodies, the world body included.
    pub nbody: usize,
    /// Bodies that must exist by name.
    pub bodies: &'a [&'a str],
}

/// The MuJoCo simulation and episode bookkeeping shared by the locomotion envs.
///
/// Actions in `[-1, 1]` are mapped linearly onto each actuator's `ctrlrange`
/// (`ctrl = centre + a * half_width`); the step runs `frame_skip` physics steps and
/// turns any MuJoCo warning into [`EnvError::Simulation`]. Nothing here allocates
/// after construction.
pub(crate) struct Sim {
    /// The MuJoCo model and state.
    pub data: mujoco::Data,
    init_qpos: Vec<f64>,
    ctrl_centre: Vec<f64>,
    ctrl_half: Vec<f64>,
    frame_skip: usize,
    max_steps: usize,
    /// Env steps taken in the current episode.
    pub steps: usize,
    started: bool,
    done: bool,
}

impl Sim {
    /// Loads `xml` and checks it has `shape` and control-limited actuators.
    pub fn load(
        xml: &str,
        shape: &ModelShape,
        frame_skip: usize,
        max_steps: usize,
    ) -> Result<Self, EnvError> {
        let model = mujoco::load_model(xml)?;
        let ffi = model.ffi();
        let dims = [
            ("nq", ffi.nq, shape.nq),
            ("nv", ffi.nv, shape.nv),
            ("nu", ffi.nu, shape.nu),
            ("nbody", ffi.nbody, shape.nbody),
        ];
        for (what, got, want) in dims {
            if usize::try_from(got).ok() != Some(want) {
                return Err(model_error(format!(
                    "{what} = {got}, expected {want} for the {} model",
                    shape.env
                )));
            }
        }
        for name in shape.bodies {
            if model.name_to_id(MjtObjBase::mjOBJ_BODY, name).is_none() {
                return Err(model_error(format!("no body named {name:?}")));
            }
        }
        Self::from_model(model, frame_skip, max_steps)
    }

    /// A simulation of any `model` whose actuators all have a finite `ctrlrange`
    /// (actions in `[-1, 1]` are scaled onto it), e.g. a user's task file.
    pub fn from_model(
        model: MjModel,
        frame_skip: usize,
        max_steps: usize,
    ) -> Result<Self, EnvError> {
        let limited = model.actuator_ctrllimited();
        let ranges = model.actuator_ctrlrange();
        let mut ctrl_centre = Vec::with_capacity(ranges.len());
        let mut ctrl_half = Vec::with_capacity(ranges.len());
        for (i, (lim, r)) in limited.iter().zip(ranges).enumerate() {
            let ok = *lim && r[0].is_finite() && r[1].is_finite() && r[0] < r[1];
            if !ok {
                let name = model
                    .id_to_name(MjtObjBase::mjOBJ_ACTUATOR, i)
                    .map(|n| format!(" ({n:?})"))
                    .unwrap_or_default();
                return Err(model_error(format!(
                    "actuator {i}{name} needs a finite ctrlrange with lo < hi (actions in \
                     [-1, 1] are scaled onto it)"
                )));
            }
            ctrl_centre.push(0.5 * (r[0] + r[1]));
            ctrl_half.push(0.5 * (r[1] - r[0]));
        }
        let init_qpos = model.qpos0().to_vec();
        let data = mujoco::new_data(model)?;
        Ok(Self {
            data,
            init_qpos,
            ctrl_centre,
            ctrl_half,
            frame_skip,
            max_steps,
            steps: 0,
            started: false,
            done: false,
        })
    }

    /// Number of actuators (the action length).
    pub fn n_actuators(&self) -> usize {
        self.ctrl_centre.len()
    }

    /// Seconds of simulated time per env step (`timestep * frame_skip`).
    pub fn dt(&self) -> f64 {
        self.data.model().opt().timestep * self.frame_skip as f64
    }

    /// Starts an episode: the model's default pose plus `U(-noise, noise)` on every
    /// position coordinate, and `U(-noise, noise)` on every velocity (Gymnasium's
    /// `reset_model`), deterministic given `seed`. Runs `mj_forward` so derived
    /// quantities match the new state.
    pub fn reset(&mut self, seed: u64, noise: f64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        // mj_resetData also clears the warning counters.
        self.data.reset();
        for (q, q0) in self.data.qpos_mut().iter_mut().zip(&self.init_qpos) {
            *q = q0 + noise * (2.0 * rng.random::<f64>() - 1.0);
        }
        for v in self.data.qvel_mut() {
            *v = noise * (2.0 * rng.random::<f64>() - 1.0);
        }
        self.data.forward();
        self.steps = 0;
        self.started = true;
        self.done = false;
    }

    /// Checks the episode may step and the buffers are valid.
    pub fn check_step(&self, action: &[f32], obs: &[f32], obs_dim: usize) -> Result<(), EnvError> {
        check_can_step(self.started, self.done, self.steps)?;
        check_action(action, self.ctrl_centre.len())?;
        check_obs_len(obs, obs_dim)
    }

    /// Writes the scaled controls for `action` (clamped to `[-1, 1]`), runs
    /// `frame_skip` physics steps and counts the env step. Returns `|ctrl|^2`. A MuJoCo
    /// warning ends the episode with [`EnvError::Simulation`].
    pub fn advance(&mut self, action: &[f32]) -> Result<f64, EnvError> {
        let mut ctrl_sq = 0.0;
        let ctrl = self.data.ctrl_mut();
        for (((c, a), centre), half) in ctrl
            .iter_mut()
            .zip(action)
            .zip(&self.ctrl_centre)
            .zip(&self.ctrl_half)
        {
            *c = centre + half * f64::from(*a).clamp(-1.0, 1.0);
            ctrl_sq += *c * *c;
        }
        for _ in 0..self.frame_skip {
            self.data.step();
        }
        self.steps += 1;
        if let Err(e) = mujoco::check_warnings(&self.data, self.steps) {
            self.done = true;
            return Err(e);
        }
        Ok(ctrl_sq)
    }

    /// Ends the step: the episode is over when `terminated` or at `max_steps`.
    pub fn finish(&mut self, terminated: bool) -> crate::env::StepOutcome {
        let truncated = !terminated && self.steps >= self.max_steps;
        self.done = terminated || truncated;
        crate::env::StepOutcome {
            terminated,
            truncated,
        }
    }

    /// Length of [`Sim::save_state`]'s output.
    pub fn state_len(&self) -> usize {
        mujoco::physics_state_len(&self.data) + 3
    }

    /// Appends the physics state, step count and episode flags to `w`.
    pub(crate) fn save_state(&self, w: &mut StateWriter) {
        let mut physics = Vec::new();
        mujoco::physics_state(&self.data, &mut physics);
        w.put(&physics)
            .count(self.steps)
            .flag(self.started)
            .flag(self.done);
    }

    /// Restores what [`Sim::save_state`] wrote, read from `r`.
    pub(crate) fn load_state(
        &mut self,
        r: &mut StateReader<'_>,
        env: &str,
    ) -> Result<(), EnvError> {
        let physics = r.take(mujoco::physics_state_len(&self.data));
        let steps = r.count("steps", self.max_steps)?;
        let started = r.flag("started")?;
        let done = r.flag("done")?;
        mujoco::set_physics_state(&mut self.data, physics, env)?;
        self.steps = steps;
        self.started = started;
        self.done = done;
        Ok(())
    }

    /// MuJoCo warning counters, by warning type, since the last reset.
    pub fn warning_counts(&self) -> Vec<i32> {
        mujoco::warning_counts(&self.data)
    }

    /// Overwrites the state with `qpos` (len `nq`) and `qvel` (len `nv`) and runs
    /// `mj_forward`; the episode goes on from there.
    pub fn set_state(&mut self, qpos: &[f64], qvel: &[f64]) -> Result<(), EnvError> {
        let (nq, nv) = (self.data.qpos().len(), self.data.qvel().len());
        for (field, len, want) in [("qpos", qpos.len(), nq), ("qvel", qvel.len(), nv)] {
            if len != want {
                return Err(EnvError::BadParam {
                    field,
                    value: format!("a slice of length {len}"),
                    reason: format!("must have length {want}"),
                });
            }
        }
        if let Some(i) = qpos.iter().chain(qvel).position(|x| !x.is_finite()) {
            return Err(EnvError::BadParam {
                field: if i < nq { "qpos" } else { "qvel" },
                value: "a non-finite value".into(),
                reason: "must be finite".into(),
            });
        }
        self.data.qpos_mut().copy_from_slice(qpos);
        self.data.qvel_mut().copy_from_slice(qvel);
        self.data.forward();
        Ok(())
    }
}

/// What every locomotion env type (a struct with fields `cfg`, `sim: Sim`,
/// `weights: RewardWeights` and `terms: RewardTerms`, and consts `NQ` and `NV`) has in
/// the same words: its `Debug` impl and the state, timing, warning and per-mode reward
/// accessors that read `sim` and `terms`.
macro_rules! loco_env_common {
    ($env:ident) => {
        impl fmt::Debug for $env {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.debug_struct(stringify!($env))
                    .field("cfg", &self.cfg)
                    .field("qpos", &self.sim.data.qpos())
                    .field("qvel", &self.sim.data.qvel())
                    .field("steps", &self.sim.steps)
                    .field("terms", &self.terms)
                    .finish_non_exhaustive()
            }
        }

        impl $env {
            /// Current generalised positions (len [`Self::NQ`]).
            pub fn qpos(&self) -> &[f64] {
                self.sim.data.qpos()
            }

            /// Current generalised velocities (len [`Self::NV`]).
            pub fn qvel(&self) -> &[f64] {
                self.sim.data.qvel()
            }

            /// Overwrites the state (like Gymnasium's `set_state`), for tests and probes; the
            /// episode goes on from it. Wrong lengths or non-finite values are
            /// [`EnvError::BadParam`] naming `qpos` or `qvel`.
            pub fn set_state(&mut self, qpos: &[f64], qvel: &[f64]) -> Result<(), EnvError> {
                self.sim.set_state(qpos, qvel)
            }

            /// Seconds of simulated time per env step.
            pub fn dt(&self) -> f64 {
                self.sim.dt()
            }

            /// Physics timestep of the model, in seconds.
            pub fn timestep(&self) -> f64 {
                self.sim.data.model().opt().timestep
            }

            /// Steps taken in the current episode.
            pub fn steps(&self) -> usize {
                self.sim.steps
            }

            /// MuJoCo warning counters, by warning type, since the last reset.
            pub fn warning_counts(&self) -> Vec<i32> {
                self.sim.warning_counts()
            }

            /// Reward of `mode` for the last transition (the start state's before the first
            /// step), in `f64`.
            pub fn mode_reward(&self, mode: LocoMode) -> f64 {
                self.terms.reward(mode, &self.weights)
            }
        }
    };
}
pub(crate) use loco_env_common;

/// Converts `src` to `f32` into the front of `dst` (as much as fits); returns the
/// rest of `dst`.
pub(crate) fn put<'a>(dst: &'a mut [f32], src: &[f64]) -> &'a mut [f32] {
    let (head, rest) = dst.split_at_mut(src.len().min(dst.len()));
    for (o, x) in head.iter_mut().zip(src) {
        *o = *x as f32;
    }
    rest
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: RewardWeights = RewardWeights {
        healthy_reward: 1.0,
        forward_weight: 2.0,
    };

    #[test]
    fn the_shared_reward_is_blind_to_direction_and_punishes_the_fall() {
        let t = |healthy, x_velocity| RewardTerms {
            healthy,
            x_velocity,
            ctrl_cost: 0.5,
            contact_cost: 0.0,
        };
        // 0.6 * forward_weight (2) * |vx| + 0.3; no control cost.
        assert!((t(true, 1.5).shared(&W) - 2.1).abs() < 1e-12);
        assert_eq!(t(true, 1.5).shared(&W), t(true, -1.5).shared(&W));
        assert!((t(true, 0.0).shared(&W) - 0.3).abs() < 1e-12);
        assert!((t(false, 0.0).shared(&W) + 30.0).abs() < 1e-12);
    }

    #[test]
    fn modes_round_trip_through_their_index() {
        for (i, m) in LocoMode::ALL.into_iter().enumerate() {
            assert_eq!(m.index(), i);
            assert_eq!(LocoMode::from_index(i), Some(m));
        }
        assert_eq!(LocoMode::from_index(3), None);
        let names: Vec<_> = LocoMode::ALL.iter().map(|m| m.name()).collect();
        assert_eq!(names, ["forward", "backward", "balance"]);
    }

    #[test]
    fn mode_rewards_follow_the_formula() {
        let t = RewardTerms {
            healthy: true,
            x_velocity: 1.5,
            ctrl_cost: 0.25,
            contact_cost: 0.5,
        };
        let mut r = [0.0f32; 3];
        t.write_rewards(&W, &mut r);
        assert_eq!(r, [1.0 + 3.0 - 0.75, 1.0 - 3.0 - 0.75, 1.0 - 3.0 - 0.75]);
        let back = RewardTerms {
            x_velocity: -1.5,
            ..t
        };
        back.write_rewards(&W, &mut r);
        assert_eq!(r, [1.0 - 3.0 - 0.75, 1.0 + 3.0 - 0.75, 1.0 - 3.0 - 0.75]);
        let fallen = RewardTerms {
            healthy: false,
            x_velocity: 0.0,
            ..t
        };
        fallen.write_rewards(&W, &mut r);
        assert_eq!(r, [-0.75; 3]);
        // A short buffer gets the first modes.
        let mut two = [0.0f32; 2];
        t.write_rewards(&W, &mut two);
        assert_eq!(two, [3.25, -2.75]);
    }

    #[test]
    fn balance_is_best_served_by_standing_still() {
        let still = RewardTerms {
            healthy: true,
            ..Default::default()
        };
        for vx in [-2.0, -0.1, 0.1, 2.0] {
            let moving = RewardTerms {
                x_velocity: vx,
                ..still
            };
            assert!(
                still.reward(LocoMode::Balance, &W) > moving.reward(LocoMode::Balance, &W),
                "{vx}"
            );
        }
    }

    #[test]
    fn open_ranges_exclude_their_ends() {
        assert!(in_open_range(1.0, [0.8, 2.0]));
        assert!(!in_open_range(0.8, [0.8, 2.0]));
        assert!(!in_open_range(2.0, [0.8, 2.0]));
        assert!(!in_open_range(f64::NAN, [0.8, 2.0]));
    }
}
