//! Walker2d on MuJoCo with three behaviour modes (paper Sec. 4 "Task setup (4)", Fig. 4
//! left): run forward, run backward, balance in place.
//!
//! The planar biped has Gymnasium Walker2d-v5's dimensions and dynamics, in an MJCF
//! written for this crate ([`WALKER2D_MJCF`]): a torso capsule of radius 0.05 from
//! 1.05 m to 1.45 m, per leg a thigh (radius 0.05, 1.05 m to 0.6 m), a leg (radius
//! 0.04, 0.6 m to 0.1 m) and a foot (radius 0.06, 0.2 m forward at 0.1 m) on hinges
//! about `-y` (thigh and leg `[-150, 0]` degrees, foot `[-45, 45]`), joint armature
//! 0.01 and damping 0.1, density 1000, friction 0.9 on the limbs and 1.9 on both feet
//! (v5), one motor of gear 100 per hinge with `ctrlrange` `[-1, 1]` (so actions are the
//! controls), RK4 with timestep 0.002 s and a frame skip of 4 (0.008 s per env step).
//! The root has three joints: `rootx` (slide), `rootz` (slide, reading the torso
//! height) and `rooty` (hinge, the torso pitch).
//!
//! The observation is v5's (17 floats): `qpos[1..9]` (torso height, torso angle, six
//! joint angles) then `qvel` (9) clipped to `[-qvel_clip, qvel_clip]` (10 by default).
//!
//! The step is healthy when the torso height lies in `healthy_z_range` (0.8, 2.0) and
//! its angle in `healthy_angle_range` (-1, 1); an unhealthy step ends the episode
//! `terminated` (v5's `terminate_when_unhealthy`), and the step reaching `max_steps`
//! (1000) is `truncated`. Episodes start from the default pose (torso at 1.25 m) plus
//! `U(-0.005, 0.005)` on every `qpos` and `qvel` entry.
//!
//! Rewards: see [`crate::locomotion`]; for this env
//! `r_k = 1 * [healthy] + 1 * v_k - 1e-3 |a|^2` with `vx` the torso's x-velocity
//! `(x_after - x_before) / dt`.

use std::fmt;

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

/// The Walker2d model: Gymnasium Walker2d-v5's planar biped (see the module docs),
/// timestep 0.002 s, RK4. Limb geoms collide with the floor only.
pub const WALKER2D_MJCF: &str = r#"<mujoco model="ess_walker2d">
  <compiler angle="degree" inertiafromgeom="true" autolimits="true"/>
  <option timestep="0.002" integrator="RK4"/>
  <default>
    <joint type="hinge" axis="0 -1 0" armature="0.01" damping="0.1"/>
    <geom type="capsule" density="1000" condim="3" contype="1" conaffinity="0" friction="0.9 0.1 0.1"/>
    <motor gear="100" ctrlrange="-1 1"/>
    <default class="root">
      <joint armature="0" damping="0" stiffness="0"/>
    </default>
    <default class="foot">
      <geom friction="1.9 0.1 0.1"/>
    </default>
  </default>
  <worldbody>
    <geom name="floor" type="plane" size="40 40 40" conaffinity="1" friction="0.7 0.1 0.1"/>
    <body name="torso" pos="0 0 1.25">
      <joint name="rootx" class="root" type="slide" axis="1 0 0"/>
      <joint name="rootz" class="root" type="slide" axis="0 0 1" ref="1.25"/>
      <joint name="rooty" class="root" type="hinge" axis="0 1 0"/>
      <geom name="torso_geom" fromto="0 0 0.2 0 0 -0.2" size="0.05"/>
      <body name="thigh" pos="0 0 -0.2">
        <joint name="thigh_joint" range="-150 0"/>
        <geom name="thigh_geom" fromto="0 0 0 0 0 -0.45" size="0.05"/>
        <body name="leg" pos="0 0 -0.45">
          <joint name="leg_joint" range="-150 0"/>
          <geom name="leg_geom" fromto="0 0 0 0 0 -0.5" size="0.04"/>
          <body name="foot" pos="0 0 -0.5">
            <joint name="foot_joint" range="-45 45"/>
            <geom name="foot_geom" class="foot" fromto="0 0 0 0.2 0 0" size="0.06"/>
          </body>
        </body>
      </body>
      <body name="thigh_left" pos="0 0 -0.2">
        <joint name="thigh_left_joint" range="-150 0"/>
        <geom name="thigh_left_geom" fromto="0 0 0 0 0 -0.45" size="0.05"/>
        <body name="leg_left" pos="0 0 -0.45">
          <joint name="leg_left_joint" range="-150 0"/>
          <geom name="leg_left_geom" fromto="0 0 0 0 0 -0.5" size="0.04"/>
          <body name="foot_left" pos="0 0 -0.5">
            <joint name="foot_left_joint" range="-45 45"/>
            <geom name="foot_left_geom" class="foot" fromto="0 0 0 0.2 0 0" size="0.06"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="thigh" joint="thigh_joint"/>
    <motor name="leg" joint="leg_joint"/>
    <motor name="foot" joint="foot_joint"/>
    <motor name="thigh_left" joint="thigh_left_joint"/>
    <motor name="leg_left" joint="leg_left_joint"/>
    <motor name="foot_left" joint="foot_left_joint"/>
  </actuator>
</mujoco>
"#;

/// Parameters of [`Walker2d`]; the defaults are Gymnasium Walker2d-v5's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Walker2dConfig {
    /// Episode length in env steps.
    pub max_steps: usize,
    /// Physics steps per env step.
    pub frame_skip: usize,
    /// Reward for every step that ends healthy.
    pub healthy_reward: f64,
    /// Weight of the mode velocity in the reward.
    pub forward_weight: f64,
    /// Weight of the control cost `|a|^2`.
    pub ctrl_cost_weight: f64,
    /// Open range of healthy torso heights, in metres.
    pub healthy_z_range: [f64; 2],
    /// Open range of healthy torso angles, in radians.
    pub healthy_angle_range: [f64; 2],
    /// Half-width of the uniform noise added to the initial `qpos` and `qvel`.
    pub reset_noise_scale: f64,
    /// Velocities in the observation are clipped to `[-qvel_clip, qvel_clip]`.
    pub qvel_clip: f64,
}

impl Default for Walker2dConfig {
    fn default() -> Self {
        Self {
            max_steps: 1000,
            frame_skip: 4,
            healthy_reward: 1.0,
            forward_weight: 1.0,
            ctrl_cost_weight: 1e-3,
            healthy_z_range: [0.8, 2.0],
            healthy_angle_range: [-1.0, 1.0],
            reset_noise_scale: 5e-3,
            qvel_clip: 10.0,
        }
    }
}

impl Walker2dConfig {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), EnvError> {
        check_positive("max_steps", self.max_steps)?;
        check_positive("frame_skip", self.frame_skip)?;
        check_non_negative("healthy_reward", self.healthy_reward)?;
        check_non_negative("forward_weight", self.forward_weight)?;
        check_non_negative("ctrl_cost_weight", self.ctrl_cost_weight)?;
        check_range("healthy_z_range", self.healthy_z_range)?;
        check_range("healthy_angle_range", self.healthy_angle_range)?;
        check_non_negative("reset_noise_scale", self.reset_noise_scale)?;
        check_non_negative("qvel_clip", self.qvel_clip)?;
        if self.qvel_clip == 0.0 {
            return Err(EnvError::BadParam {
                field: "qvel_clip",
                value: "0".into(),
                reason: "must be positive".into(),
            });
        }
        Ok(())
    }
}

/// The three-mode Walker2d environment; see the module docs.
pub struct Walker2d {
    cfg: Walker2dConfig,
    spec: EnvSpec,
    sim: Sim,
    weights: RewardWeights,
    /// Reward terms of the last step (the start state's before the first).
    terms: RewardTerms,
}

crate::locomotion::loco_env_common!(Walker2d);

impl Walker2d {
    /// Observation length (v5's).
    pub const OBS_DIM: usize = 17;
    /// Action length.
    pub const ACT_DIM: usize = 6;
    /// Position coordinates of the model.
    pub const NQ: usize = 9;
    /// Degrees of freedom of the model.
    pub const NV: usize = 9;

    /// Builds the env on [`WALKER2D_MJCF`] after validating `cfg`. Call [`Env::reset`]
    /// before stepping.
    pub fn new(cfg: Walker2dConfig) -> Result<Self, EnvError> {
        Self::from_mjcf(WALKER2D_MJCF, cfg)
    }

    /// Builds the env on the MJCF model `xml`, which must have `nq = nv = 9` (root
    /// x-slide, z-slide, y-hinge, then six hinges), six control-limited actuators,
    /// eight bodies (world included) and a body named `torso`. A model MuJoCo rejects,
    /// or one of another shape, is [`EnvError::Model`].
    pub fn from_mjcf(xml: &str, cfg: Walker2dConfig) -> Result<Self, EnvError> {
        cfg.validate()?;
        let shape = ModelShape {
            env: "walker2d",
            nq: Self::NQ,
            nv: Self::NV,
            nu: Self::ACT_DIM,
            nbody: 8,
            bodies: &[TORSO],
        };
        let sim = Sim::load(xml, &shape, cfg.frame_skip, cfg.max_steps)?;
        let spec = EnvSpec {
            name: "walker2d".into(),
            obs_dim: Self::OBS_DIM,
            act_dim: Self::ACT_DIM,
            n_modes: N_MODES,
            max_steps: cfg.max_steps,
        };
        let weights = RewardWeights {
            healthy_reward: cfg.healthy_reward,
            forward_weight: cfg.forward_weight,
        };
        Ok(Self {
            cfg,
            spec,
            sim,
            weights,
            terms: RewardTerms::default(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &Walker2dConfig {
        &self.cfg
    }

    /// Height of the torso centre (`qpos[1]`), in metres.
    pub fn torso_height(&self) -> f64 {
        self.sim.data.qpos()[1]
    }

    /// Pitch of the torso (`qpos[2]`), in radians.
    pub fn torso_angle(&self) -> f64 {
        self.sim.data.qpos()[2]
    }

    /// x-position of the torso (`qpos[0]`), in metres.
    pub fn x_position(&self) -> f64 {
        self.sim.data.qpos()[0]
    }

    /// x-velocity of the torso over the last step, in m/s (0 before the first step).
    pub fn x_velocity(&self) -> f64 {
        self.terms.x_velocity
    }

    /// Whether the current state is healthy (torso height and angle in range).
    pub fn is_healthy(&self) -> bool {
        in_open_range(self.torso_height(), self.cfg.healthy_z_range)
            && in_open_range(self.torso_angle(), self.cfg.healthy_angle_range)
    }

    fn write_obs(&self, obs: &mut [f32]) {
        let rest = put(obs, &self.sim.data.qpos()[1..]);
        let clip = self.cfg.qvel_clip;
        for (o, v) in rest.iter_mut().zip(self.sim.data.qvel()) {
            *o = v.clamp(-clip, clip) as f32;
        }
    }
}

impl Env for Walker2d {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), EnvError> {
        check_obs_len(obs, Self::OBS_DIM)?;
        self.sim.reset(seed, self.cfg.reset_noise_scale);
        self.terms = RewardTerms {
            healthy: self.is_healthy(),
            ..RewardTerms::default()
        };
        self.write_obs(obs);
        Ok(())
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<StepOutcome, EnvError> {
        self.sim.check_step(action, obs, Self::OBS_DIM)?;
        let x_before = self.x_position();
        let ctrl_sq = self.sim.advance(action)?;
        let healthy = self.is_healthy();
        self.terms = RewardTerms {
            healthy,
            x_velocity: (self.x_position() - x_before) / self.sim.dt(),
            ctrl_cost: self.cfg.ctrl_cost_weight * ctrl_sq,
            contact_cost: 0.0,
        };
        self.write_obs(obs);
        Ok(self.sim.finish(!healthy))
    }

    fn mode_rewards(&self, out: &mut [f32]) {
        self.terms.write_rewards(&self.weights, out);
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

    /// `[MuJoCo integration state, steps, started, done, last step's reward terms]`.
    fn state(&self) -> Vec<f64> {
        let mut w = StateWriter::default();
        self.sim.save_state(&mut w);
        self.terms.save(&mut w);
        w.finish()
    }

    fn set_state(&mut self, state: &[f64]) -> Result<(), EnvError> {
        let len = self.sim.state_len() + RewardTerms::STATE_LEN;
        let mut r = StateReader::new(&self.spec.name, state, len)?;
        self.sim.load_state(&mut r, &self.spec.name)?;
        self.terms = RewardTerms::load(&mut r)?;
        Ok(())
    }
}

/// The registry's entry ([`crate::registry`]): forward, backward, balance; trained
/// experts.
pub const ENTRY: EnvEntry = EnvEntry {
    name: "walker2d",
    build: Build::Trained(|n_modes| {
        check_n_modes("walker2d", n_modes)?;
        Ok(Box::new(Walker2d::new(Walker2dConfig::default())?))
    }),
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::conformance::{
        assert_bad_params, assert_malformed_mjcf, assert_random_controls_raise_no_warning,
        assert_wrong_shape_mjcf, check_env, random_rollout,
    };
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::f64::consts::PI;

    fn env() -> Walker2d {
        Walker2d::new(Walker2dConfig::default()).expect("walker2d")
    }

    fn short(max_steps: usize) -> Walker2d {
        Walker2d::new(Walker2dConfig {
            max_steps,
            ..Default::default()
        })
        .expect("walker2d")
    }

    #[test]
    fn walker2d_passes_the_conformance_suite() {
        check_env("walker2d", &|| Box::new(short(200)));
    }

    #[test]
    fn the_model_has_v5_timing_spaces_and_episode_length() {
        let env = env();
        assert!((env.timestep() - 0.002).abs() < 1e-12);
        assert!((env.dt() - 0.008).abs() < 1e-12);
        let s = env.spec();
        assert_eq!(
            (s.obs_dim, s.act_dim, s.n_modes, s.max_steps),
            (17, 6, 3, 1000)
        );
        assert_eq!(s.name, "walker2d");
    }

    #[test]
    fn the_default_pose_matches_the_standard_walker() {
        let mut env = Walker2d::new(Walker2dConfig {
            reset_noise_scale: 0.0,
            ..Default::default()
        })
        .expect("env");
        let mut obs = [0.0; Walker2d::OBS_DIM];
        env.reset(0, &mut obs).expect("reset");
        assert_eq!(env.qpos(), &[0.0, 1.25, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        assert!(env.qvel().iter().all(|&v| v == 0.0));
        assert!(env.is_healthy());
        // Feet: capsules of radius 0.06 at 0.1 m, from x = 0 to 0.2.
        let model = env.sim.data.model();
        let foot = model
            .name_to_id(mujoco_rs::prelude::MjtObjBase::mjOBJ_GEOM, "foot_geom")
            .expect("foot geom");
        let p = env.sim.data.geom_xpos()[foot];
        assert!(
            (p[0] - 0.1).abs() < 1e-9 && (p[2] - 0.1).abs() < 1e-9,
            "{p:?}"
        );
        // Total mass: density-1000 capsules (radius, length) of the standard walker.
        let capsule = |r: f64, l: f64| 1000.0 * PI * r * r * (l + 4.0 * r / 3.0);
        let want = capsule(0.05, 0.4)
            + 2.0 * (capsule(0.05, 0.45) + capsule(0.04, 0.5) + capsule(0.06, 0.2));
        let mass: f64 = model.body_mass().iter().sum();
        assert!((mass - want).abs() < 1e-9, "mass {mass}, want {want}");
    }

    #[test]
    fn observation_is_qpos_without_x_then_clipped_qvel() {
        let mut env = env();
        let mut obs = [0.0; Walker2d::OBS_DIM];
        env.reset(3, &mut obs).expect("reset");
        let mut qvel = env.qvel().to_vec();
        qvel[3] = 25.0;
        qvel[4] = -30.0;
        let qpos = env.qpos().to_vec();
        env.set_state(&qpos, &qvel).expect("state");
        env.step(&[0.3, -0.2, 0.1, 0.0, 0.5, -0.5], &mut obs)
            .expect("step");
        let (q, v) = (env.qpos(), env.qvel());
        for i in 0..8 {
            assert_eq!(obs[i], q[i + 1] as f32, "qpos[{}]", i + 1);
        }
        for i in 0..9 {
            assert_eq!(obs[8 + i], v[i].clamp(-10.0, 10.0) as f32, "qvel[{i}]");
        }
        assert!(obs[8..].iter().all(|x| x.abs() <= 10.0));
        assert_eq!(f64::from(obs[0]), env.torso_height() as f32 as f64);
    }

    #[test]
    fn reset_noise_is_uniform_within_the_scale() {
        let mut env = env();
        let mut obs = [0.0; Walker2d::OBS_DIM];
        let mut max = 0.0f64;
        for seed in 0..50 {
            env.reset(seed, &mut obs).expect("reset");
            let q0 = [0.0, 1.25, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
            for (q, z) in env.qpos().iter().zip(q0) {
                assert!((q - z).abs() <= 5e-3);
                max = max.max((q - z).abs());
            }
            assert!(env.qvel().iter().all(|v| v.abs() <= 5e-3));
        }
        assert!(max > 4e-3, "{max}");
    }

    #[test]
    fn pushing_the_torso_forward_rewards_forward_over_backward() {
        let mut env = env();
        let mut obs = [0.0; Walker2d::OBS_DIM];
        let mut r = [0.0f32; 3];
        for (vx, best, worst) in [(2.0, 0, 1), (-2.0, 1, 0)] {
            env.reset(1, &mut obs).expect("reset");
            let mut qvel = env.qvel().to_vec();
            qvel[0] = vx;
            let qpos = env.qpos().to_vec();
            env.set_state(&qpos, &qvel).expect("state");
            env.step(&[0.0; 6], &mut obs).expect("step");
            env.mode_rewards(&mut r);
            let v = env.forward_velocity().expect("velocity");
            assert!(v * vx > 0.0 && v.abs() > 1.0, "vx {vx}: measured {v}");
            assert!((v - env.x_velocity()).abs() < 1e-12);
            assert!(r[best] > r[2] + 2.0, "vx {vx}: {r:?}");
            // Balance pays -|vx|: the same as running the wrong way.
            assert!((r[2] - r[worst]).abs() < 1e-5, "vx {vx}: {r:?}");
            // Healthy reward 1, no control cost.
            let want = 1.0 + v.abs();
            assert!((f64::from(r[best]) - want).abs() < 1e-4, "{r:?} vs {want}");
            // The shared reward pays speed either way: 0.6 |vx| + 0.3 upright.
            let shared = f64::from(env.shared_reward());
            assert!((shared - (0.6 * v.abs() + 0.3)).abs() < 1e-4, "{shared}");
        }
    }

    #[test]
    fn standing_still_scores_the_healthy_reward_in_every_mode() {
        let mut env = Walker2d::new(Walker2dConfig {
            reset_noise_scale: 0.0,
            ..Default::default()
        })
        .expect("env");
        let mut obs = [0.0; Walker2d::OBS_DIM];
        env.reset(0, &mut obs).expect("reset");
        let mut r = [0.0f32; 3];
        env.mode_rewards(&mut r);
        assert_eq!(r, [1.0; 3], "start state");
        let mut t = [0.0f32; 3];
        env.task_rewards(&mut t);
        assert_eq!(r, t);
        // One step of full torque costs 1e-3 * 6.
        env.step(&[1.0; 6], &mut obs).expect("step");
        env.mode_rewards(&mut r);
        let v = env.x_velocity();
        for m in LocoMode::ALL {
            let want = 1.0 + m.velocity(v) - 6e-3;
            assert!((f64::from(r[m.index()]) - want).abs() < 1e-5, "{m:?}");
            assert!((env.mode_reward(m) - want).abs() < 1e-9);
        }
    }

    #[test]
    fn zero_actions_end_in_a_fall_or_at_the_time_limit_consistently() {
        let mut env = env();
        let mut obs = [0.0; Walker2d::OBS_DIM];
        for seed in 0..3 {
            env.reset(seed, &mut obs).expect("reset");
            let out = loop {
                let out = env.step(&[0.0; 6], &mut obs).expect("step");
                if out.done() {
                    break out;
                }
                assert!(env.is_healthy());
            };
            assert!(out.terminated != out.truncated);
            if out.terminated {
                assert!(!env.is_healthy());
                let (z, a) = (env.torso_height(), env.torso_angle());
                assert!(!(z > 0.8 && z < 2.0 && a.abs() < 1.0), "z {z} angle {a}");
                let mut r = [0.0f32; 3];
                env.mode_rewards(&mut r);
                // No healthy reward on the terminating step.
                assert!(r.iter().all(|&x| x < 0.9), "{r:?}");
            } else {
                assert_eq!(env.steps(), 1000);
            }
        }
    }

    #[test]
    fn a_tilted_torso_terminates() {
        let mut env = env();
        let mut obs = [0.0; Walker2d::OBS_DIM];
        env.reset(0, &mut obs).expect("reset");
        let mut qpos = env.qpos().to_vec();
        qpos[2] = 1.2;
        let qvel = env.qvel().to_vec();
        env.set_state(&qpos, &qvel).expect("state");
        let out = env.step(&[0.0; 6], &mut obs).expect("step");
        assert!(out.terminated && !out.truncated);
        // The fall costs the shared reward 0.3 * 100; mode rewards only lose the
        // healthy reward.
        let shared = f64::from(env.shared_reward());
        let want = 0.6 * env.x_velocity().abs() - 30.0;
        assert!((shared - want).abs() < 1e-4, "{shared} vs {want}");
        let mut r = [0.0f32; 3];
        env.mode_rewards(&mut r);
        assert!(r.iter().all(|&x| x > -10.0), "{r:?}");
    }

    #[test]
    fn random_controls_over_ten_episodes_raise_no_mujoco_warning() {
        assert_random_controls_raise_no_warning(&mut env(), 10, Walker2d::warning_counts);
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
        assert_bad_params::<Walker2dConfig, _>(
            Walker2d::new,
            &[
                ("max_steps", |c| c.max_steps = 0),
                ("frame_skip", |c| c.frame_skip = 0),
                ("healthy_reward", |c| c.healthy_reward = f64::NAN),
                ("ctrl_cost_weight", |c| c.ctrl_cost_weight = -1.0),
                ("healthy_z_range", |c| c.healthy_z_range = [2.0, 0.8]),
                ("healthy_angle_range", |c| {
                    c.healthy_angle_range = [-1.0, f64::INFINITY]
                }),
                ("reset_noise_scale", |c| c.reset_noise_scale = -0.1),
                ("qvel_clip", |c| c.qvel_clip = 0.0),
            ],
        );
    }

    #[test]
    fn set_state_rejects_wrong_lengths_and_non_finite_values() {
        let mut env = env();
        let err = env.set_state(&[0.0; 8], &[0.0; 9]).unwrap_err();
        assert!(err.to_string().contains("qpos"), "{err}");
        let err = env.set_state(&[0.0; 9], &[0.0; 10]).unwrap_err();
        assert!(err.to_string().contains("qvel"), "{err}");
        let mut v = [0.0; 9];
        v[4] = f64::NAN;
        let err = env.set_state(&[0.0; 9], &v).unwrap_err();
        assert!(err.to_string().contains("qvel"), "{err}");
    }

    #[test]
    fn a_malformed_mjcf_string_is_a_clear_model_error() {
        assert_malformed_mjcf(|xml| Walker2d::from_mjcf(xml, Walker2dConfig::default()));
    }

    #[test]
    fn an_mjcf_of_the_wrong_shape_is_a_model_error_saying_what_is_wrong() {
        let m = WALKER2D_MJCF;
        assert_wrong_shape_mjcf(
            |xml| Walker2d::from_mjcf(xml, Walker2dConfig::default()),
            &[
                (m.replace("name=\"torso\"", "name=\"trunk\""), "torso"),
                (
                    m.replace("<motor name=\"foot_left\" joint=\"foot_left_joint\"/>", ""),
                    "nu = 5",
                ),
                (
                    m.replace(
                        "<joint name=\"rootz\" class=\"root\" type=\"slide\" axis=\"0 0 1\" ref=\"1.25\"/>",
                        "",
                    ),
                    "nq = 8",
                ),
                (m.replace("ctrlrange=\"-1 1\"", ""), "ctrlrange"),
            ],
        );
    }

    #[test]
    fn an_unstable_model_fails_loudly_instead_of_resetting() {
        let unstable = WALKER2D_MJCF
            .replace(
                "armature=\"0.01\" damping=\"0.1\"",
                "armature=\"0\" damping=\"0\"",
            )
            .replace("gear=\"100\"", "gear=\"1e9\"");
        let mut env = Walker2d::from_mjcf(&unstable, Walker2dConfig::default()).expect("env");
        let mut obs = [0.0; Walker2d::OBS_DIM];
        env.reset(0, &mut obs).expect("reset");
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let err = loop {
            let a: [f32; 6] = std::array::from_fn(|_| rng.random_range(-1.0..=1.0));
            match env.step(&a, &mut obs) {
                Ok(out) if out.done() => {
                    env.reset(1, &mut obs).expect("reset");
                }
                Ok(_) => {}
                Err(e) => break e,
            }
        };
        assert!(matches!(err, EnvError::Simulation { .. }), "{err}");
        let err = env.step(&[0.0; 6], &mut obs).unwrap_err();
        assert!(matches!(err, EnvError::StepAfterDone { .. }), "{err}");
    }
}
