//! Humanoid on MuJoCo with three behaviour modes (paper Sec. 4 "Task setup (5)", Fig. 4
//! right): run forward, run backward, balance in place.
//!
//! The 3D biped has Gymnasium Humanoid-v5's dimensions and dynamics, in an MJCF written
//! for this crate ([`HUMANOID_MJCF`]): a free-floating torso (capsule, head sphere,
//! upper waist) starting at 1.4 m, lower waist and pelvis on three abdomen hinges,
//! per leg a thigh on three hip hinges, a shin on a knee hinge and a spherical foot,
//! per arm an upper arm on two shoulder hinges and a forearm with hand on an elbow
//! hinge: 13 bodies, 17 hinges (`nq = 24`, `nv = 23`), 17 motors (gears 100 on abdomen
//! and hips x/z, 300 on hips y, 200 on knees, 25 on arms) with `ctrlrange`
//! `[-0.4, 0.4]`, RK4 with timestep 0.003 s, Newton solver with 50 iterations, and a
//! frame skip of 5 (0.015 s per env step).
//!
//! **Actions.** The [`Env`] contract takes actions in `[-1, 1]`; they are scaled
//! linearly onto the `ctrlrange`, so `ctrl = 0.4 * a` and an action of 1 is v5's
//! largest control. The control cost is v5's, on the controls: `0.1 |ctrl|^2`.
//!
//! **Observation** (v5's layout, 348 floats by default): `qpos[2..]` (22: torso height,
//! orientation quaternion, joint angles), `qvel` (23), then `cinert` (13 x 10), `cvel`
//! (13 x 6), `qfrc_actuator` of the 17 hinge dofs and `cfrc_ext` (13 x 6) of every body
//! but the world body. Each of the last four blocks can be dropped with its
//! `include_*` flag ([`HumanoidConfig`]). As in v5 (which calls
//! `mj_rnePostConstraint` after stepping so that `cfrc_ext` holds the contact forces),
//! the derived quantities are the ones `mj_step` leaves: computed at the start of the
//! last physics substep.
//!
//! **Episodes** start from the default pose plus `U(-0.01, 0.01)` on every `qpos` and
//! `qvel` entry. A step is healthy when the torso height `qpos[2]` lies in
//! `healthy_z_range` (1.0, 2.0); an unhealthy step ends the episode `terminated`, and
//! the step reaching `max_steps` (1000) is `truncated`.
//!
//! **Rewards**: see [`crate::locomotion`]; for this env
//! `r_k = 5 * [healthy] + 1.25 * v_k - 0.1 |ctrl|^2 - min(5e-7 |cfrc_ext|^2, 10)`,
//! with `vx` the x-velocity of the centre of mass (mass-weighted body `xipos`) over the
//! step, as v5 computes it.
//! That is the evaluation reward ([`Env::mode_rewards`]). The *task* reward experts
//! train on ([`Env::task_rewards`]) is the same with `1.25` replaced by
//! `task_forward_weight` (4 by default): under v5's weights a PPO expert learns to
//! stand long before it learns to move, since standing alone earns 5 per step.

use std::fmt;

use mujoco_rs::prelude::{MjtJoint, MjtObjBase};
use serde::{Deserialize, Serialize};

use crate::env::{
    Build, Env, EnvEntry, EnvError, EnvSpec, StateReader, StateWriter, StepOutcome, check_obs_len,
};
use crate::locomotion::{
    LocoMode, ModelShape, N_MODES, RewardTerms, RewardWeights, Sim, check_n_modes,
    check_non_negative, check_positive, check_range, in_open_range, put,
};

/// Name of the torso body the model must define.
const TORSO: &str = "torso";

/// The Humanoid model: Gymnasium Humanoid-v5's biped (see the module docs), timestep
/// 0.003 s, RK4. Every body geom collides with every other (except parent and child)
/// and with the floor.
pub const HUMANOID_MJCF: &str = r#"<mujoco model="ess_humanoid">
  <compiler angle="degree" inertiafromgeom="true" autolimits="true"/>
  <option timestep="0.003" integrator="RK4" solver="Newton" iterations="50"/>
  <default>
    <joint type="hinge" armature="1" damping="1"/>
    <geom type="capsule" contype="1" conaffinity="1" condim="1" margin="0.001"/>
    <motor ctrlrange="-0.4 0.4"/>
    <default class="trunk">
      <joint armature="0.02" damping="5"/>
    </default>
    <default class="hip">
      <joint armature="0.01" damping="5"/>
    </default>
  </default>
  <worldbody>
    <geom name="floor" type="plane" size="20 20 0.125" condim="3" friction="1 0.1 0.1"/>
    <body name="torso" pos="0 0 1.4">
      <freejoint name="root"/>
      <geom name="torso1" fromto="0 -0.07 0 0 0.07 0" size="0.07"/>
      <geom name="head" type="sphere" pos="0 0 0.19" size="0.09"/>
      <geom name="uwaist" fromto="-0.01 -0.06 -0.12 -0.01 0.06 -0.12" size="0.06"/>
      <body name="lwaist" pos="-0.01 0 -0.26" quat="1 0 -0.002 0">
        <geom name="lwaist" fromto="0 -0.06 0 0 0.06 0" size="0.06"/>
        <joint name="abdomen_z" class="trunk" pos="0 0 0.065" axis="0 0 1" range="-45 45" stiffness="20"/>
        <joint name="abdomen_y" class="trunk" pos="0 0 0.065" axis="0 1 0" range="-75 30" stiffness="10"/>
        <body name="pelvis" pos="0 0 -0.165" quat="1 0 -0.002 0">
          <joint name="abdomen_x" class="trunk" pos="0 0 0.1" axis="1 0 0" range="-35 35" stiffness="10"/>
          <geom name="butt" fromto="-0.02 -0.07 0 -0.02 0.07 0" size="0.09"/>
          <body name="right_thigh" pos="0 -0.1 -0.04">
            <joint name="right_hip_x" class="hip" axis="1 0 0" range="-25 5" stiffness="10"/>
            <joint name="right_hip_z" class="hip" axis="0 0 1" range="-60 35" stiffness="10"/>
            <joint name="right_hip_y" class="hip" axis="0 1 0" range="-110 20" stiffness="20" armature="0.008"/>
            <geom name="right_thigh1" fromto="0 0 0 0 0.01 -0.34" size="0.06"/>
            <body name="right_shin" pos="0 0.01 -0.403">
              <joint name="right_knee" pos="0 0 0.02" axis="0 -1 0" range="-160 -2" armature="0.006"/>
              <geom name="right_shin1" fromto="0 0 0 0 0 -0.3" size="0.049"/>
              <body name="right_foot" pos="0 0 -0.45">
                <geom name="right_foot" type="sphere" pos="0 0 0.1" size="0.075"/>
              </body>
            </body>
          </body>
          <body name="left_thigh" pos="0 0.1 -0.04">
            <joint name="left_hip_x" class="hip" axis="-1 0 0" range="-25 5" stiffness="10"/>
            <joint name="left_hip_z" class="hip" axis="0 0 -1" range="-60 35" stiffness="10"/>
            <joint name="left_hip_y" class="hip" axis="0 1 0" range="-110 20" stiffness="20"/>
            <geom name="left_thigh1" fromto="0 0 0 0 -0.01 -0.34" size="0.06"/>
            <body name="left_shin" pos="0 -0.01 -0.403">
              <joint name="left_knee" pos="0 0 0.02" axis="0 -1 0" range="-160 -2" stiffness="1" armature="0.006"/>
              <geom name="left_shin1" fromto="0 0 0 0 0 -0.3" size="0.049"/>
              <body name="left_foot" pos="0 0 -0.45">
                <geom name="left_foot" type="sphere" pos="0 0 0.1" size="0.075"/>
              </body>
            </body>
          </body>
        </body>
      </body>
      <body name="right_upper_arm" pos="0 -0.17 0.06">
        <joint name="right_shoulder1" axis="2 1 1" range="-85 60" stiffness="1" armature="0.0068"/>
        <joint name="right_shoulder2" axis="0 -1 1" range="-85 60" stiffness="1" armature="0.0051"/>
        <geom name="right_uarm1" fromto="0 0 0 0.16 -0.16 -0.16" size="0.04"/>
        <body name="right_lower_arm" pos="0.18 -0.18 -0.18">
          <joint name="right_elbow" axis="0 -1 1" range="-90 50" armature="0.0028"/>
          <geom name="right_larm" fromto="0.01 0.01 0.01 0.17 0.17 0.17" size="0.031"/>
          <geom name="right_hand" type="sphere" pos="0.18 0.18 0.18" size="0.04"/>
        </body>
      </body>
      <body name="left_upper_arm" pos="0 0.17 0.06">
        <joint name="left_shoulder1" axis="2 -1 1" range="-60 85" stiffness="1" armature="0.0068"/>
        <joint name="left_shoulder2" axis="0 1 1" range="-60 85" stiffness="1" armature="0.0051"/>
        <geom name="left_uarm1" fromto="0 0 0 0.16 0.16 -0.16" size="0.04"/>
        <body name="left_lower_arm" pos="0.18 0.18 -0.18">
          <joint name="left_elbow" axis="0 -1 -1" range="-90 50" armature="0.0028"/>
          <geom name="left_larm" fromto="0.01 -0.01 0.01 0.17 -0.17 0.17" size="0.031"/>
          <geom name="left_hand" type="sphere" pos="0.18 -0.18 0.18" size="0.04"/>
        </body>
      </body>
    </body>
  </worldbody>
  <tendon>
    <fixed name="left_hipknee">
      <joint joint="left_hip_y" coef="-1"/>
      <joint joint="left_knee" coef="1"/>
    </fixed>
    <fixed name="right_hipknee">
      <joint joint="right_hip_y" coef="-1"/>
      <joint joint="right_knee" coef="1"/>
    </fixed>
  </tendon>
  <actuator>
    <motor name="abdomen_y" joint="abdomen_y" gear="100"/>
    <motor name="abdomen_z" joint="abdomen_z" gear="100"/>
    <motor name="abdomen_x" joint="abdomen_x" gear="100"/>
    <motor name="right_hip_x" joint="right_hip_x" gear="100"/>
    <motor name="right_hip_z" joint="right_hip_z" gear="100"/>
    <motor name="right_hip_y" joint="right_hip_y" gear="300"/>
    <motor name="right_knee" joint="right_knee" gear="200"/>
    <motor name="left_hip_x" joint="left_hip_x" gear="100"/>
    <motor name="left_hip_z" joint="left_hip_z" gear="100"/>
    <motor name="left_hip_y" joint="left_hip_y" gear="300"/>
    <motor name="left_knee" joint="left_knee" gear="200"/>
    <motor name="right_shoulder1" joint="right_shoulder1" gear="25"/>
    <motor name="right_shoulder2" joint="right_shoulder2" gear="25"/>
    <motor name="right_elbow" joint="right_elbow" gear="25"/>
    <motor name="left_shoulder1" joint="left_shoulder1" gear="25"/>
    <motor name="left_shoulder2" joint="left_shoulder2" gear="25"/>
    <motor name="left_elbow" joint="left_elbow" gear="25"/>
  </actuator>
</mujoco>
"#;

/// Parameters of [`Humanoid`]; the defaults are Gymnasium Humanoid-v5's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HumanoidConfig {
    /// Episode length in env steps.
    pub max_steps: usize,
    /// Physics steps per env step.
    pub frame_skip: usize,
    /// Reward for every step that ends healthy.
    pub healthy_reward: f64,
    /// Weight of the mode velocity in the reward.
    pub forward_weight: f64,
    /// Weight of the mode velocity in the *task* reward that experts train on
    /// ([`Env::task_rewards`]); the evaluation reward keeps `forward_weight`. Larger
    /// than v5's 1.25 so that moving outweighs merely standing: with 1.25 a standing
    /// policy earns 5 of the 6.25 that running at 1 m/s pays, and PPO's experts only
    /// stood (bench/mujoco.md).
    pub task_forward_weight: f64,
    /// Weight of the control cost `|ctrl|^2`.
    pub ctrl_cost_weight: f64,
    /// Weight of the contact cost `|cfrc_ext|^2`.
    pub contact_cost_weight: f64,
    /// The weighted contact cost is clipped to at most this.
    pub contact_cost_max: f64,
    /// Open range of healthy torso heights, in metres.
    pub healthy_z_range: [f64; 2],
    /// Half-width of the uniform noise added to the initial `qpos` and `qvel`.
    pub reset_noise_scale: f64,
    /// Observe the bodies' com-based inertias (`cinert`, 13 x 10).
    pub include_cinert: bool,
    /// Observe the bodies' com-based velocities (`cvel`, 13 x 6).
    pub include_cvel: bool,
    /// Observe the actuator forces on the 17 hinge dofs (`qfrc_actuator`).
    pub include_qfrc_actuator: bool,
    /// Observe the bodies' external (contact) forces (`cfrc_ext`, 13 x 6).
    pub include_cfrc_ext: bool,
}

impl Default for HumanoidConfig {
    fn default() -> Self {
        Self {
            max_steps: 1000,
            frame_skip: 5,
            healthy_reward: 5.0,
            forward_weight: 1.25,
            task_forward_weight: 4.0,
            ctrl_cost_weight: 0.1,
            contact_cost_weight: 5e-7,
            contact_cost_max: 10.0,
            healthy_z_range: [1.0, 2.0],
            reset_noise_scale: 1e-2,
            include_cinert: true,
            include_cvel: true,
            include_qfrc_actuator: true,
            include_cfrc_ext: true,
        }
    }
}

impl HumanoidConfig {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), EnvError> {
        check_positive("max_steps", self.max_steps)?;
        check_positive("frame_skip", self.frame_skip)?;
        check_non_negative("healthy_reward", self.healthy_reward)?;
        check_non_negative("forward_weight", self.forward_weight)?;
        check_non_negative("task_forward_weight", self.task_forward_weight)?;
        check_non_negative("ctrl_cost_weight", self.ctrl_cost_weight)?;
        check_non_negative("contact_cost_weight", self.contact_cost_weight)?;
        check_non_negative("contact_cost_max", self.contact_cost_max)?;
        check_range("healthy_z_range", self.healthy_z_range)?;
        check_non_negative("reset_noise_scale", self.reset_noise_scale)
    }

    /// Observation length under these flags (348 with all four blocks, as v5).
    pub fn obs_dim(&self) -> usize {
        let bodies = Humanoid::N_BODIES - 1;
        let mut n = (Humanoid::NQ - 2) + Humanoid::NV;
        n += usize::from(self.include_cinert) * bodies * 10;
        n += usize::from(self.include_cvel) * bodies * 6;
        n += usize::from(self.include_qfrc_actuator) * (Humanoid::NV - 6);
        n += usize::from(self.include_cfrc_ext) * bodies * 6;
        n
    }
}

/// The three-mode Humanoid environment; see the module docs.
pub struct Humanoid {
    cfg: HumanoidConfig,
    spec: EnvSpec,
    sim: Sim,
    weights: RewardWeights,
    /// Weights of the task reward experts train on (`task_forward_weight`).
    task_weights: RewardWeights,
    /// Body masses over the total mass, for the centre of mass.
    mass_fraction: Vec<f64>,
    /// Reward terms of the last step (the start state's before the first).
    terms: RewardTerms,
    /// Centre-of-mass x from the body positions `mj_step` left (see
    /// [`Humanoid::center_of_mass_x`]); kept so a restored state steps identically.
    com_x: f64,
}

crate::locomotion::loco_env_common!(Humanoid);

impl Humanoid {
    /// Action length.
    pub const ACT_DIM: usize = 17;
    /// Position coordinates of the model (free joint 7 + 17 hinges).
    pub const NQ: usize = 24;
    /// Degrees of freedom of the model (free joint 6 + 17 hinges).
    pub const NV: usize = 23;
    /// Bodies of the model, the world body included.
    pub const N_BODIES: usize = 14;
    /// Observation length with the default (v5) flags.
    pub const DEFAULT_OBS_DIM: usize = 348;

    /// Builds the env on [`HUMANOID_MJCF`] after validating `cfg`. Call [`Env::reset`]
    /// before stepping.
    pub fn new(cfg: HumanoidConfig) -> Result<Self, EnvError> {
        Self::from_mjcf(HUMANOID_MJCF, cfg)
    }

    /// Builds the env on the MJCF model `xml`, which must have `nq = 24`, `nv = 23`
    /// (a free joint first, then 17 hinges), 17 control-limited actuators, 14 bodies
    /// (world included) and a body named `torso` carrying the free joint. A model
    /// MuJoCo rejects, or one of another shape, is [`EnvError::Model`].
    pub fn from_mjcf(xml: &str, cfg: HumanoidConfig) -> Result<Self, EnvError> {
        cfg.validate()?;
        let shape = ModelShape {
            env: "humanoid",
            nq: Self::NQ,
            nv: Self::NV,
            nu: Self::ACT_DIM,
            nbody: Self::N_BODIES,
            bodies: &[TORSO],
        };
        let sim = Sim::load(xml, &shape, cfg.frame_skip, cfg.max_steps)?;
        let model = sim.data.model();
        let torso = model.name_to_id(MjtObjBase::mjOBJ_BODY, TORSO);
        let torso_has_root = model
            .jnt_type()
            .first()
            .is_some_and(|t| *t == MjtJoint::mjJNT_FREE)
            && model
                .jnt_bodyid()
                .first()
                .and_then(|&b| usize::try_from(b).ok())
                == torso;
        if !torso_has_root {
            return Err(EnvError::Model {
                reason: "the first joint must be a free joint on body \"torso\"".into(),
            });
        }
        let total: f64 = model.body_mass().iter().sum();
        if !(total.is_finite() && total > 0.0) {
            return Err(EnvError::Model {
                reason: format!("total body mass {total} is not positive"),
            });
        }
        let mass_fraction = model.body_mass().iter().map(|m| m / total).collect();
        let spec = EnvSpec {
            name: "humanoid".into(),
            obs_dim: cfg.obs_dim(),
            act_dim: Self::ACT_DIM,
            n_modes: N_MODES,
            max_steps: cfg.max_steps,
        };
        let weights = RewardWeights {
            healthy_reward: cfg.healthy_reward,
            forward_weight: cfg.forward_weight,
        };
        let task_weights = RewardWeights {
            forward_weight: cfg.task_forward_weight,
            ..weights
        };
        Ok(Self {
            cfg,
            spec,
            sim,
            weights,
            task_weights,
            mass_fraction,
            terms: RewardTerms::default(),
            com_x: 0.0,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &HumanoidConfig {
        &self.cfg
    }

    /// Height of the torso (`qpos[2]`), in metres.
    pub fn torso_height(&self) -> f64 {
        self.sim.data.qpos()[2]
    }

    /// x-position of the torso (`qpos[0]`), in metres.
    pub fn x_position(&self) -> f64 {
        self.sim.data.qpos()[0]
    }

    /// x-coordinate of the centre of mass, from the body positions `mj_step` left
    /// (v5's `mass_center`), in metres.
    pub fn center_of_mass_x(&self) -> f64 {
        self.com_x
    }

    /// [`Humanoid::center_of_mass_x`] computed from the current body positions.
    fn com_from_bodies(&self) -> f64 {
        self.sim
            .data
            .xipos()
            .iter()
            .zip(&self.mass_fraction)
            .map(|(p, w)| p[0] * w)
            .sum()
    }

    /// x-velocity of the centre of mass over the last step, in m/s (0 before the
    /// first step).
    pub fn x_velocity(&self) -> f64 {
        self.terms.x_velocity
    }

    /// Weighted, clipped contact cost of the last step.
    pub fn contact_cost(&self) -> f64 {
        self.terms.contact_cost
    }

    /// Whether the current state is healthy (torso height in range).
    pub fn is_healthy(&self) -> bool {
        in_open_range(self.torso_height(), self.cfg.healthy_z_range)
    }

    fn contact_cost_now(&self) -> f64 {
        let sq: f64 = self
            .sim
            .data
            .cfrc_ext()
            .iter()
            .flat_map(|f| f.iter())
            .map(|x| x * x)
            .sum();
        (self.cfg.contact_cost_weight * sq).min(self.cfg.contact_cost_max)
    }

    fn write_obs(&self, obs: &mut [f32]) {
        let d = &self.sim.data;
        let mut rest = put(obs, &d.qpos()[2..]);
        rest = put(rest, d.qvel());
        if self.cfg.include_cinert {
            rest = put(rest, d.cinert()[1..].as_flattened());
        }
        if self.cfg.include_cvel {
            rest = put(rest, d.cvel()[1..].as_flattened());
        }
        if self.cfg.include_qfrc_actuator {
            rest = put(rest, &d.qfrc_actuator()[6..]);
        }
        if self.cfg.include_cfrc_ext {
            put(rest, d.cfrc_ext()[1..].as_flattened());
        }
    }
}

impl Env for Humanoid {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), EnvError> {
        check_obs_len(obs, self.spec.obs_dim)?;
        self.sim.reset(seed, self.cfg.reset_noise_scale);
        // v5 fills cfrc_ext after every step; do it for the start state too.
        self.sim.data.rne_post_constraint();
        self.com_x = self.com_from_bodies();
        self.terms = RewardTerms {
            healthy: self.is_healthy(),
            ..RewardTerms::default()
        };
        self.write_obs(obs);
        Ok(())
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<StepOutcome, EnvError> {
        self.sim.check_step(action, obs, self.spec.obs_dim)?;
        let com_before = self.com_x;
        let ctrl_sq = self.sim.advance(action)?;
        // mj_step leaves cfrc_ext unset unless a sensor needs it; v5 computes it here.
        self.sim.data.rne_post_constraint();
        self.com_x = self.com_from_bodies();
        let healthy = self.is_healthy();
        self.terms = RewardTerms {
            healthy,
            x_velocity: (self.com_x - com_before) / self.sim.dt(),
            ctrl_cost: self.cfg.ctrl_cost_weight * ctrl_sq,
            contact_cost: self.contact_cost_now(),
        };
        self.write_obs(obs);
        Ok(self.sim.finish(!healthy))
    }

    fn mode_rewards(&self, out: &mut [f32]) {
        self.terms.write_rewards(&self.weights, out);
    }

    /// The evaluation reward with the mode velocity weighted by `task_forward_weight`.
    fn task_rewards(&self, out: &mut [f32]) {
        self.terms.write_rewards(&self.task_weights, out);
    }

    fn shared_reward(&self) -> f32 {
        self.terms.shared(&self.weights) as f32
    }

    fn forward_velocity(&self) -> Option<f64> {
        Some(self.terms.x_velocity)
    }

    fn scene(&self) -> Option<crate::scene::Scene> {
        Some(crate::mujoco::scene(&self.sim.data, self.sim.dt()))
    }

    fn body_poses(&self) -> Vec<crate::scene::Pose> {
        crate::mujoco::poses(&self.sim.data)
    }

    /// `[MuJoCo integration state, steps, started, done, last step's reward terms,
    /// centre-of-mass x]`.
    fn state(&self) -> Vec<f64> {
        let mut w = StateWriter::default();
        self.sim.save_state(&mut w);
        self.terms.save(&mut w);
        w.put(&[self.com_x]).finish()
    }

    fn set_state(&mut self, state: &[f64]) -> Result<(), EnvError> {
        let len = self.sim.state_len() + RewardTerms::STATE_LEN + 1;
        let mut r = StateReader::new(&self.spec.name, state, len)?;
        self.sim.load_state(&mut r, &self.spec.name)?;
        self.terms = RewardTerms::load(&mut r)?;
        self.com_x = r.scalar();
        Ok(())
    }
}

/// The registry's entry ([`crate::registry`]): forward, backward, balance; trained
/// experts.
pub const ENTRY: EnvEntry = EnvEntry {
    name: "humanoid",
    build: Build::Trained(|n_modes| {
        check_n_modes("humanoid", n_modes)?;
        Ok(Box::new(Humanoid::new(HumanoidConfig::default())?))
    }),
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::conformance::{
        assert_bad_params, assert_malformed_mjcf, assert_random_controls_raise_no_warning,
        assert_wrong_shape_mjcf, check_env, random_rollout,
    };

    fn env() -> Humanoid {
        Humanoid::new(HumanoidConfig::default()).expect("humanoid")
    }

    fn quiet() -> Humanoid {
        Humanoid::new(HumanoidConfig {
            reset_noise_scale: 0.0,
            ..Default::default()
        })
        .expect("humanoid")
    }

    /// The default pose: torso at 1.4 m, identity orientation, hinges at 0.
    fn default_qpos() -> [f64; Humanoid::NQ] {
        let mut q = [0.0; Humanoid::NQ];
        q[2] = 1.4;
        q[3] = 1.0;
        q
    }

    #[test]
    fn humanoid_passes_the_conformance_suite() {
        check_env("humanoid", &|| Box::new(env()));
        check_env("humanoid-small", &|| {
            Box::new(
                Humanoid::new(HumanoidConfig {
                    include_cinert: false,
                    include_cfrc_ext: false,
                    max_steps: 10,
                    ..Default::default()
                })
                .expect("humanoid"),
            )
        });
    }

    #[test]
    fn the_model_has_v5_timing_spaces_and_episode_length() {
        let env = env();
        assert!((env.timestep() - 0.003).abs() < 1e-12);
        assert!((env.dt() - 0.015).abs() < 1e-12);
        let s = env.spec();
        assert_eq!(
            (s.obs_dim, s.act_dim, s.n_modes, s.max_steps),
            (348, 17, 3, 1000)
        );
        assert_eq!(s.obs_dim, Humanoid::DEFAULT_OBS_DIM);
        assert_eq!(s.name, "humanoid");
        let model = env.sim.data.model();
        assert!(
            model
                .actuator_ctrlrange()
                .iter()
                .all(|r| r[0] == -0.4 && r[1] == 0.4)
        );
    }

    #[test]
    fn observation_flags_drop_their_blocks() {
        let all = HumanoidConfig::default();
        let cases = [
            (
                HumanoidConfig {
                    include_cinert: false,
                    ..all.clone()
                },
                348 - 130,
            ),
            (
                HumanoidConfig {
                    include_cvel: false,
                    ..all.clone()
                },
                348 - 78,
            ),
            (
                HumanoidConfig {
                    include_qfrc_actuator: false,
                    ..all.clone()
                },
                348 - 17,
            ),
            (
                HumanoidConfig {
                    include_cfrc_ext: false,
                    ..all.clone()
                },
                348 - 78,
            ),
            (
                HumanoidConfig {
                    include_cinert: false,
                    include_cvel: false,
                    include_qfrc_actuator: false,
                    include_cfrc_ext: false,
                    ..all.clone()
                },
                45,
            ),
        ];
        for (cfg, dim) in cases {
            assert_eq!(cfg.obs_dim(), dim);
            let mut env = Humanoid::new(cfg).expect("env");
            assert_eq!(env.spec().obs_dim, dim);
            let mut obs = vec![0.0; dim];
            env.reset(0, &mut obs).expect("reset");
            env.step(&[0.1; 17], &mut obs).expect("step");
        }
    }

    #[test]
    fn observation_follows_the_v5_layout() {
        let mut env = env();
        let mut obs = vec![0.0; 348];
        env.reset(2, &mut obs).expect("reset");
        // Walk until the feet touch the floor so cfrc_ext is non-zero.
        for _ in 0..20 {
            env.step(&[0.2; 17], &mut obs).expect("step");
        }
        let d = &env.sim.data;
        let mut want: Vec<f64> = d.qpos()[2..].to_vec();
        want.extend_from_slice(d.qvel());
        want.extend(d.cinert()[1..].iter().flatten());
        want.extend(d.cvel()[1..].iter().flatten());
        want.extend_from_slice(&d.qfrc_actuator()[6..]);
        want.extend(d.cfrc_ext()[1..].iter().flatten());
        assert_eq!(want.len(), 348);
        for (i, (o, w)) in obs.iter().zip(&want).enumerate() {
            assert_eq!(*o, *w as f32, "obs[{i}]");
        }
        // The blocks carry information: torso height first, forces of the feet on.
        assert_eq!(obs[0], env.torso_height() as f32);
        let cfrc = &obs[348 - 78..];
        assert!(
            cfrc.iter().any(|&x| x.abs() > 1.0),
            "no contact force observed"
        );
        let qfrc = &obs[348 - 78 - 17..348 - 78];
        assert!(
            qfrc.iter().any(|&x| x.abs() > 1.0),
            "no actuator force observed"
        );
        // World body blocks are excluded: cinert[0] would be all zero.
        assert!(obs[45..55].iter().any(|&x| x != 0.0));
    }

    #[test]
    fn actions_are_scaled_onto_the_control_range() {
        let mut env = quiet();
        let mut obs = vec![0.0; 348];
        env.reset(0, &mut obs).expect("reset");
        let mut a = [0.0f32; 17];
        a[0] = 1.0;
        a[1] = -0.5;
        a[2] = 3.0; // clamped to 1
        env.step(&a, &mut obs).expect("step");
        let ctrl = env.sim.data.ctrl();
        assert!((ctrl[0] - 0.4).abs() < 1e-12);
        assert!((ctrl[1] + 0.2).abs() < 1e-12);
        assert!((ctrl[2] - 0.4).abs() < 1e-12);
        assert!(ctrl[3..].iter().all(|&c| c == 0.0));
        let want_ctrl_cost = 0.1 * (0.16 + 0.04 + 0.16);
        let mut r = [0.0f32; 3];
        env.mode_rewards(&mut r);
        let v = env.x_velocity();
        let want = 5.0 + 1.25 * v - want_ctrl_cost - env.contact_cost();
        assert!((f64::from(r[0]) - want).abs() < 1e-5, "{r:?} vs {want}");
    }

    #[test]
    fn reset_noise_is_uniform_within_the_scale() {
        let mut env = env();
        let mut obs = vec![0.0; 348];
        let q0 = default_qpos();
        let mut max = 0.0f64;
        for seed in 0..30 {
            env.reset(seed, &mut obs).expect("reset");
            for (q, z) in env.qpos().iter().zip(q0) {
                assert!((q - z).abs() <= 1e-2);
                max = max.max((q - z).abs());
            }
            assert!(env.qvel().iter().all(|v| v.abs() <= 1e-2));
            assert!(env.is_healthy());
        }
        assert!(max > 9e-3, "{max}");
        let mut q = quiet();
        q.reset(0, &mut obs).expect("reset");
        assert_eq!(q.qpos(), &default_qpos());
    }

    #[test]
    fn pushing_the_body_forward_or_backward_rewards_the_matching_mode() {
        let mut env = quiet();
        let mut obs = vec![0.0; 348];
        let mut r = [0.0f32; 3];
        for (vx, best, worst) in [(1.5, 0, 1), (-1.5, 1, 0)] {
            env.reset(0, &mut obs).expect("reset");
            let mut qvel = [0.0; Humanoid::NV];
            qvel[0] = vx;
            env.set_state(&default_qpos(), &qvel).expect("state");
            env.step(&[0.0; 17], &mut obs).expect("step");
            env.mode_rewards(&mut r);
            let v = env.forward_velocity().expect("velocity");
            assert!(v * vx > 0.0 && v.abs() > 1.0, "vx {vx}: measured {v}");
            assert!(r[best] > r[2] + 2.0, "vx {vx}: {r:?}");
            assert!((r[2] - r[worst]).abs() < 1e-5, "vx {vx}: {r:?}");
            // Healthy 5, no control; the airborne body has no contact cost.
            assert_eq!(env.contact_cost(), 0.0);
            let want = 5.0 + 1.25 * v.abs();
            assert!((f64::from(r[best]) - want).abs() < 1e-4, "{r:?} vs {want}");
            // The task reward weighs the velocity by task_forward_weight (4) instead.
            let mut t = [0.0f32; 3];
            env.task_rewards(&mut t);
            let want = 5.0 + 4.0 * v.abs();
            assert!((f64::from(t[best]) - want).abs() < 1e-4, "{t:?} vs {want}");
            assert!((f64::from(t[2] - t[worst])).abs() < 1e-5, "vx {vx}: {t:?}");
        }
    }

    #[test]
    fn the_start_state_scores_the_healthy_reward_in_every_mode() {
        let mut env = quiet();
        let mut obs = vec![0.0; 348];
        env.reset(0, &mut obs).expect("reset");
        let mut r = [0.0f32; 3];
        env.mode_rewards(&mut r);
        assert_eq!(r, [5.0; 3]);
        for m in LocoMode::ALL {
            assert_eq!(env.mode_reward(m), 5.0);
        }
    }

    #[test]
    fn the_centre_of_mass_velocity_matches_a_uniform_push() {
        // Every body moves at vx: the centre of mass does too.
        let mut env = quiet();
        let mut obs = vec![0.0; 348];
        env.reset(0, &mut obs).expect("reset");
        let mut qvel = [0.0; Humanoid::NV];
        qvel[0] = 1.0;
        env.set_state(&default_qpos(), &qvel).expect("state");
        let x0 = env.center_of_mass_x();
        env.step(&[0.0; 17], &mut obs).expect("step");
        let v = env.x_velocity();
        assert!((v - 1.0).abs() < 0.05, "{v}");
        assert!(env.center_of_mass_x() > x0);
    }

    #[test]
    fn zero_actions_make_the_humanoid_fall_and_terminate() {
        let mut env = env();
        let mut obs = vec![0.0; 348];
        for seed in 0..3 {
            env.reset(seed, &mut obs).expect("reset");
            let out = loop {
                let out = env.step(&[0.0; 17], &mut obs).expect("step");
                if out.done() {
                    break out;
                }
                assert!(env.is_healthy());
            };
            assert!(out.terminated && !out.truncated, "{out:?}");
            assert!(env.steps() < 200, "{} steps", env.steps());
            assert!(env.torso_height() <= 1.0, "{}", env.torso_height());
            let mut r = [0.0f32; 3];
            env.mode_rewards(&mut r);
            assert!(r.iter().all(|&x| x < 4.0), "no healthy reward: {r:?}");
        }
    }

    #[test]
    fn a_lifted_torso_terminates_above_the_healthy_range() {
        let mut env = quiet();
        let mut obs = vec![0.0; 348];
        env.reset(0, &mut obs).expect("reset");
        let mut q = default_qpos();
        q[2] = 2.5;
        env.set_state(&q, &[0.0; Humanoid::NV]).expect("state");
        let out = env.step(&[0.0; 17], &mut obs).expect("step");
        assert!(out.terminated && !out.truncated);
    }

    #[test]
    fn contact_cost_is_clipped() {
        let mut env = Humanoid::new(HumanoidConfig {
            contact_cost_weight: 1.0,
            ..Default::default()
        })
        .expect("env");
        let mut obs = vec![0.0; 348];
        env.reset(0, &mut obs).expect("reset");
        let mut max = 0.0f64;
        loop {
            let out = env.step(&[0.0; 17], &mut obs).expect("step");
            max = max.max(env.contact_cost());
            if out.done() {
                break;
            }
        }
        assert_eq!(max, 10.0);
    }

    #[test]
    fn random_controls_over_several_seeds_raise_no_mujoco_warning() {
        assert_random_controls_raise_no_warning(&mut env(), 12, Humanoid::warning_counts);
    }

    #[test]
    fn random_rollouts_are_deterministic_per_seed() {
        let (a, oa) = random_rollout(&mut env(), 5);
        let (b, ob) = random_rollout(&mut env(), 5);
        assert_eq!(a, b);
        assert_eq!(oa, ob);
    }

    #[test]
    fn invalid_config_errors_name_the_field() {
        assert_bad_params::<HumanoidConfig, _>(
            Humanoid::new,
            &[
                ("max_steps", |c| c.max_steps = 0),
                ("frame_skip", |c| c.frame_skip = 0),
                ("healthy_reward", |c| c.healthy_reward = -5.0),
                ("forward_weight", |c| c.forward_weight = f64::NAN),
                ("ctrl_cost_weight", |c| c.ctrl_cost_weight = -0.1),
                ("contact_cost_weight", |c| c.contact_cost_weight = -1.0),
                ("contact_cost_max", |c| c.contact_cost_max = f64::INFINITY),
                ("healthy_z_range", |c| c.healthy_z_range = [1.0, 1.0]),
                ("reset_noise_scale", |c| c.reset_noise_scale = f64::NAN),
            ],
        );
    }

    #[test]
    fn a_malformed_mjcf_string_is_a_clear_model_error() {
        assert_malformed_mjcf(|xml| Humanoid::from_mjcf(xml, HumanoidConfig::default()));
    }

    #[test]
    fn an_mjcf_of_the_wrong_shape_is_a_model_error_saying_what_is_wrong() {
        let m = HUMANOID_MJCF;
        assert_wrong_shape_mjcf(
            |xml| Humanoid::from_mjcf(xml, HumanoidConfig::default()),
            &[
                (m.replace("name=\"torso\"", "name=\"chest\""), "torso"),
                (
                    m.replace(
                        "<motor name=\"left_elbow\" joint=\"left_elbow\" gear=\"25\"/>",
                        "",
                    ),
                    "nu = 16",
                ),
                (m.replace("<freejoint name=\"root\"/>", ""), "nq = 17"),
                (
                    m.replace("<motor ctrlrange=\"-0.4 0.4\"/>", ""),
                    "ctrlrange",
                ),
            ],
        );
    }
}
