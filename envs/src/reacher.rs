//! Multi-target Reacher on MuJoCo (paper Sec. 4 "Task setup (2)").
//!
//! A planar two-link arm with the standard Reacher dimensions: links of 0.1 m and
//! 0.11 m (shoulder to elbow, elbow to fingertip), hinge joints about the vertical
//! axis, one motor per joint with gear 200 and control range `[-1, 1]`, physics
//! timestep 0.01 s with RK4 and a frame skip of 2 (0.02 s per env step). Episodes last
//! `max_steps` (default 50) steps and end truncated, never terminated. The MJCF
//! ([`REACHER_MJCF`]) is written for this crate; joint `armature` keeps it stable
//! under saturated random controls.
//!
//! The paper's change to the standard task: `n_modes = K` targets (`2..=12`) lie
//! evenly on a circle of radius `target_radius` (default 0.15 m; the arm reaches
//! 0.21 m) around the shoulder, target `k` at angle `2 pi k / K`, and the target is
//! *not* part of the observation, so the behaviour mode (which target to reach) is
//! latent. The observation is Gymnasium Reacher-v5's without the target terms
//! (8 floats):
//!
//! `[cos q0, cos q1, sin q0, sin q1, qd0, qd1, fingertip_x, fingertip_y]`
//!
//! Episodes start with the shoulder angle `U(-pi, pi)`, the elbow angle
//! `U(-pi/2, pi/2)` and joint velocities `U(-init_qvel_noise, init_qvel_noise)`,
//! deterministic given the reset seed.
//!
//! The evaluation reward of mode `k` is Gymnasium's:
//! `-|fingertip - target_k| - 0.1 |a|^2`, with the fingertip after the step and `a`
//! the clamped action of that step (zero before the first step).
//!
//! The scripted expert of mode `k` solves the two-link inverse kinematics for target
//! `k` (keeping the elbow on the side it currently bends toward), then drives the
//! joints there with a PD controller in action units plus Gaussian noise of standard
//! deviation `expert_noise`, clamped to `[-0.999, 0.999]`. The issue asks for
//! PPO-trained experts eventually; this scripted expert is what makes multi-modal
//! demonstrations possible now, without a trained policy.
//!
//! A MuJoCo warning during a step (for example an unstable, diverging state, which
//! MuJoCo would silently reset) is an [`EnvError::Simulation`] error, never ignored.

use std::f64::consts::PI;
use std::fmt;

use mujoco_rs::prelude::MjtObjBase;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::env::{
    Build, Env, EnvEntry, EnvError, EnvSpec, ScriptedExpert, StepOutcome, check_action,
    check_can_step, check_obs_len,
};
use crate::mujoco;

/// Length of the upper arm (shoulder to elbow), in metres.
pub const LINK0: f64 = 0.1;
/// Length of the forearm (elbow to fingertip), in metres.
pub const LINK1: f64 = 0.11;

/// Largest magnitude of an expert action.
const EXPERT_ACTION_LIMIT: f64 = 0.999;

/// Weight of the control cost `|a|^2` in the evaluation reward (Gymnasium's).
const CONTROL_COST: f64 = 0.1;

/// Name of the fingertip site the model must define.
const FINGERTIP_SITE: &str = "fingertip";

/// The Reacher model: a two-link planar arm (0.1 m and 0.11 m), hinge joints with
/// armature and damping, motors with gear 200 and `ctrlrange` `[-1, 1]`, timestep
/// 0.01 s, RK4. No collisions: every geom has `contype = conaffinity = 0`.
pub const REACHER_MJCF: &str = r#"<mujoco model="ess_reacher">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.01" integrator="RK4" gravity="0 0 -9.81"/>
  <default>
    <joint type="hinge" axis="0 0 1" armature="1" damping="1"/>
    <geom type="capsule" size="0.01" contype="0" conaffinity="0" density="1000"/>
    <motor gear="200" ctrlrange="-1 1"/>
  </default>
  <worldbody>
    <geom name="floor" type="plane" size="0.3 0.3 0.01" pos="0 0 -0.01"/>
    <body name="upper_arm" pos="0 0 0.01">
      <joint name="shoulder"/>
      <geom name="upper_arm_geom" fromto="0 0 0 0.1 0 0"/>
      <body name="forearm" pos="0.1 0 0">
        <joint name="elbow" range="-3.0 3.0"/>
        <geom name="forearm_geom" fromto="0 0 0 0.1 0 0"/>
        <site name="fingertip" pos="0.11 0 0" size="0.01"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="shoulder_motor" joint="shoulder"/>
    <motor name="elbow_motor" joint="elbow"/>
  </actuator>
</mujoco>
"#;

/// Parameters of [`Reacher`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReacherConfig {
    /// Number of targets, one per behaviour mode (`2..=12`).
    pub n_modes: usize,
    /// Radius of the circle the targets lie on, in metres; strictly between the arm's
    /// inner (`|LINK0 - LINK1|`) and outer (`LINK0 + LINK1`) reach.
    pub target_radius: f64,
    /// Episode length in env steps.
    pub max_steps: usize,
    /// Physics steps per env step.
    pub frame_skip: usize,
    /// Half-width of the uniform initial joint-velocity noise, in rad/s.
    pub init_qvel_noise: f64,
    /// Standard deviation of the expert's Gaussian action noise, in action units.
    pub expert_noise: f64,
    /// Expert proportional gain: action per radian of joint-angle error.
    pub expert_kp: f64,
    /// Expert derivative gain: action per rad/s of joint velocity.
    pub expert_kd: f64,
}

impl Default for ReacherConfig {
    fn default() -> Self {
        Self {
            n_modes: 6,
            target_radius: 0.15,
            max_steps: 50,
            frame_skip: 2,
            init_qvel_noise: 0.005,
            expert_noise: 0.05,
            expert_kp: 1.0,
            expert_kd: 0.12,
        }
    }
}

impl ReacherConfig {
    /// Smallest supported number of targets.
    pub const MIN_MODES: usize = 2;
    /// Largest supported number of targets.
    pub const MAX_MODES: usize = 12;

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), EnvError> {
        if !(Self::MIN_MODES..=Self::MAX_MODES).contains(&self.n_modes) {
            return Err(EnvError::BadParam {
                field: "n_modes",
                value: self.n_modes.to_string(),
                reason: format!(
                    "reacher supports {} to {} targets",
                    Self::MIN_MODES,
                    Self::MAX_MODES
                ),
            });
        }
        let (inner, outer) = ((LINK0 - LINK1).abs(), LINK0 + LINK1);
        if !(self.target_radius.is_finite()
            && self.target_radius > inner
            && self.target_radius < outer)
        {
            return Err(bad(
                "target_radius",
                self.target_radius,
                &format!("must lie strictly between the arm's reach limits {inner} and {outer}"),
            ));
        }
        for (field, value) in [
            ("max_steps", self.max_steps),
            ("frame_skip", self.frame_skip),
        ] {
            if value == 0 {
                return Err(EnvError::BadParam {
                    field,
                    value: "0".into(),
                    reason: "must be at least 1".into(),
                });
            }
        }
        let non_negative = [
            ("init_qvel_noise", self.init_qvel_noise),
            ("expert_noise", self.expert_noise),
            ("expert_kp", self.expert_kp),
            ("expert_kd", self.expert_kd),
        ];
        for (field, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                return Err(bad(field, value, "must be non-negative and finite"));
            }
        }
        Ok(())
    }
}

fn bad(field: &'static str, value: f64, reason: &str) -> EnvError {
    EnvError::BadParam {
        field,
        value: value.to_string(),
        reason: reason.to_owned(),
    }
}

/// The multi-target Reacher environment; see the module docs.
pub struct Reacher {
    cfg: ReacherConfig,
    spec: EnvSpec,
    data: mujoco::Data,
    fingertip: usize,
    targets: Vec<[f64; 2]>,
    /// Clamped action of the last step (zero before the first).
    last_action: [f64; 2],
    steps: usize,
    started: bool,
    done: bool,
}

impl fmt::Debug for Reacher {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Reacher")
            .field("cfg", &self.cfg)
            .field("qpos", &self.data.qpos())
            .field("qvel", &self.data.qvel())
            .field("steps", &self.steps)
            .field("started", &self.started)
            .field("done", &self.done)
            .finish_non_exhaustive()
    }
}

impl Reacher {
    /// Observation length.
    pub const OBS_DIM: usize = 8;
    /// Action length.
    pub const ACT_DIM: usize = 2;

    /// Builds the env on [`REACHER_MJCF`] after validating `cfg`. Call [`Env::reset`]
    /// before stepping.
    pub fn new(cfg: ReacherConfig) -> Result<Self, EnvError> {
        Self::from_mjcf(REACHER_MJCF, cfg)
    }

    /// Builds the env on the MJCF model `xml`, which must have two hinge joints (two
    /// position and two velocity coordinates), two actuators and a site named
    /// `fingertip`. A model MuJoCo rejects, or one of another shape, is
    /// [`EnvError::Model`].
    pub fn from_mjcf(xml: &str, cfg: ReacherConfig) -> Result<Self, EnvError> {
        cfg.validate()?;
        let model = mujoco::load_model(xml)?;
        let shape = [
            ("nq", model.ffi().nq),
            ("nv", model.ffi().nv),
            ("nu", model.ffi().nu),
        ];
        for (what, got) in shape {
            if got != 2 {
                return Err(EnvError::Model {
                    reason: format!("{what} = {got}, expected 2 (a two-joint, two-motor arm)"),
                });
            }
        }
        let fingertip = model
            .name_to_id(MjtObjBase::mjOBJ_SITE, FINGERTIP_SITE)
            .ok_or_else(|| EnvError::Model {
                reason: format!("no site named {FINGERTIP_SITE:?}"),
            })?;
        let data = mujoco::new_data(model)?;
        let k = cfg.n_modes;
        let targets = (0..k)
            .map(|i| {
                let angle = 2.0 * PI * i as f64 / k as f64;
                [
                    cfg.target_radius * angle.cos(),
                    cfg.target_radius * angle.sin(),
                ]
            })
            .collect();
        let spec = EnvSpec {
            name: "reacher".into(),
            obs_dim: Self::OBS_DIM,
            act_dim: Self::ACT_DIM,
            n_modes: k,
            max_steps: cfg.max_steps,
        };
        Ok(Self {
            cfg,
            spec,
            data,
            fingertip,
            targets,
            last_action: [0.0; 2],
            steps: 0,
            started: false,
            done: false,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &ReacherConfig {
        &self.cfg
    }

    /// Target of `mode` in the arm's plane, or `None` when out of range.
    pub fn target(&self, mode: usize) -> Option<[f64; 2]> {
        self.targets.get(mode).copied()
    }

    /// Current fingertip position in the arm's plane.
    pub fn fingertip(&self) -> [f64; 2] {
        let p = self.data.site_xpos()[self.fingertip];
        [p[0], p[1]]
    }

    /// Current joint angles `[shoulder, elbow]`.
    pub fn joint_angles(&self) -> [f64; 2] {
        let q = self.data.qpos();
        [q[0], q[1]]
    }

    /// Current joint velocities `[shoulder, elbow]`.
    pub fn joint_velocities(&self) -> [f64; 2] {
        let v = self.data.qvel();
        [v[0], v[1]]
    }

    /// Distance from the fingertip to the target of `mode`, or `None` when out of range.
    pub fn distance_to_target(&self, mode: usize) -> Option<f64> {
        let t = self.target(mode)?;
        let p = self.fingertip();
        Some((p[0] - t[0]).hypot(p[1] - t[1]))
    }

    /// Steps taken in the current episode.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Physics timestep of the model, in seconds.
    pub fn timestep(&self) -> f64 {
        self.data.model().opt().timestep
    }

    /// MuJoCo warning counters, by warning type, since the last reset.
    pub fn warning_counts(&self) -> Vec<i32> {
        mujoco::warning_counts(&self.data)
    }

    fn write_obs(&self, obs: &mut [f32]) {
        let q = self.data.qpos();
        let v = self.data.qvel();
        let p = self.fingertip();
        let values = [
            q[0].cos(),
            q[1].cos(),
            q[0].sin(),
            q[1].sin(),
            v[0],
            v[1],
            p[0],
            p[1],
        ];
        for (o, x) in obs.iter_mut().zip(values) {
            *o = x as f32;
        }
    }
}

/// Wraps an angle into `(-pi, pi]`.
fn wrap_angle(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI { w - 2.0 * PI } else { w }
}

/// Joint angles that put the fingertip at `target`, with the elbow bending to the side
/// of `elbow_sign` (`+1` or `-1`). `target` must be within the arm's reach.
fn inverse_kinematics(target: [f64; 2], elbow_sign: f64) -> [f64; 2] {
    let r2 = target[0] * target[0] + target[1] * target[1];
    let c = ((r2 - LINK0 * LINK0 - LINK1 * LINK1) / (2.0 * LINK0 * LINK1)).clamp(-1.0, 1.0);
    let elbow = elbow_sign * c.acos();
    let shoulder =
        target[1].atan2(target[0]) - (LINK1 * elbow.sin()).atan2(LINK0 + LINK1 * elbow.cos());
    [wrap_angle(shoulder), elbow]
}

impl Env for Reacher {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), EnvError> {
        check_obs_len(obs, Self::OBS_DIM)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = self.cfg.init_qvel_noise;
        let q0 = rng.random_range(-PI..=PI);
        let q1 = rng.random_range(-PI / 2.0..=PI / 2.0);
        let v0 = noise * (2.0 * rng.random::<f64>() - 1.0);
        let v1 = noise * (2.0 * rng.random::<f64>() - 1.0);
        // mj_resetData also clears the warning counters.
        self.data.reset();
        self.data.qpos_mut().copy_from_slice(&[q0, q1]);
        self.data.qvel_mut().copy_from_slice(&[v0, v1]);
        self.data.forward();
        self.last_action = [0.0; 2];
        self.steps = 0;
        self.started = true;
        self.done = false;
        self.write_obs(obs);
        Ok(())
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<StepOutcome, EnvError> {
        check_can_step(self.started, self.done, self.steps)?;
        check_action(action, Self::ACT_DIM)?;
        check_obs_len(obs, Self::OBS_DIM)?;
        let a = [
            f64::from(action[0]).clamp(-1.0, 1.0),
            f64::from(action[1]).clamp(-1.0, 1.0),
        ];
        self.data.ctrl_mut().copy_from_slice(&a);
        for _ in 0..self.cfg.frame_skip {
            self.data.step();
        }
        // mj_step leaves site positions at the state before its last integration step.
        self.data.forward_kinematics();
        self.last_action = a;
        self.steps += 1;
        if let Err(e) = mujoco::check_warnings(&self.data, self.steps) {
            self.done = true;
            return Err(e);
        }
        let truncated = self.steps >= self.cfg.max_steps;
        self.done = truncated;
        self.write_obs(obs);
        Ok(StepOutcome {
            terminated: false,
            truncated,
        })
    }

    fn scene(&self) -> Option<crate::scene::Scene> {
        let dt = self.data.model().opt().timestep * self.cfg.frame_skip as f64;
        Some(crate::mujoco::scene(&self.data, dt))
    }

    fn body_poses(&self) -> Vec<crate::scene::Pose> {
        crate::mujoco::poses(&self.data)
    }

    /// `[MuJoCo integration state, last action (2), steps, started, done]`.
    fn state(&self) -> Vec<f64> {
        mujoco::arm_state(
            &self.data,
            &self.last_action,
            self.steps,
            self.started,
            self.done,
        )
    }

    fn set_state(&mut self, state: &[f64]) -> Result<(), EnvError> {
        (self.steps, self.started, self.done) = mujoco::set_arm_state(
            &mut self.data,
            &self.spec.name,
            state,
            &mut self.last_action,
            self.cfg.max_steps,
        )?;
        Ok(())
    }

    fn mode_rewards(&self, out: &mut [f32]) {
        let p = self.fingertip();
        let ctrl = CONTROL_COST * (self.last_action[0].powi(2) + self.last_action[1].powi(2));
        for (r, t) in out.iter_mut().zip(&self.targets) {
            *r = (-(p[0] - t[0]).hypot(p[1] - t[1]) - ctrl) as f32;
        }
    }
}

impl ScriptedExpert for Reacher {
    fn expert_action(
        &self,
        mode: usize,
        rng: &mut ChaCha8Rng,
        action: &mut [f32],
    ) -> Result<(), EnvError> {
        let target = self.target(mode).ok_or(EnvError::ModeOutOfRange {
            mode,
            n_modes: self.cfg.n_modes,
        })?;
        if !self.started {
            return Err(EnvError::NotReset);
        }
        if action.len() != Self::ACT_DIM {
            return Err(EnvError::BadActionLen {
                expected: Self::ACT_DIM,
                got: action.len(),
            });
        }
        let q = self.joint_angles();
        let v = self.joint_velocities();
        let elbow_sign = if q[1] >= 0.0 { 1.0 } else { -1.0 };
        let goal = inverse_kinematics(target, elbow_sign);
        let errors = [wrap_angle(goal[0] - q[0]), goal[1] - q[1]];
        for ((slot, e), qd) in action.iter_mut().zip(errors).zip(v) {
            let noise: f64 = rng.sample(StandardNormal);
            let a =
                self.cfg.expert_kp * e - self.cfg.expert_kd * qd + self.cfg.expert_noise * noise;
            *slot = a.clamp(-EXPERT_ACTION_LIMIT, EXPERT_ACTION_LIMIT) as f32;
        }
        Ok(())
    }
}

/// The registry's entry ([`crate::registry`]): `n_modes` targets, scripted experts.
pub const ENTRY: EnvEntry = EnvEntry {
    name: "reacher",
    build: Build::Scripted(|n_modes| {
        Ok(Box::new(Reacher::new(ReacherConfig {
            n_modes,
            ..ReacherConfig::default()
        })?))
    }),
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::conformance::{
        assert_bad_params, assert_malformed_mjcf, assert_wrong_shape_mjcf,
    };

    fn env(n_modes: usize) -> Reacher {
        Reacher::new(ReacherConfig {
            n_modes,
            ..Default::default()
        })
        .expect("env")
    }

    /// Runs `episodes` episodes acting with `policy`; returns, per episode, the return
    /// of every mode and the final distance to every target.
    fn run(
        env: &mut Reacher,
        episodes: u64,
        mut policy: impl FnMut(&Reacher, &mut ChaCha8Rng) -> [f32; 2],
    ) -> Vec<(Vec<f64>, Vec<f64>)> {
        let k = env.spec().n_modes;
        let mut obs = [0.0; Reacher::OBS_DIM];
        let mut r = vec![0.0f32; k];
        (0..episodes)
            .map(|ep| {
                let mut rng = ChaCha8Rng::seed_from_u64(500 + ep);
                env.reset(ep, &mut obs).expect("reset");
                let mut ret = vec![0.0; k];
                loop {
                    let a = policy(env, &mut rng);
                    let out = env.step(&a, &mut obs).expect("step");
                    env.mode_rewards(&mut r);
                    for (s, x) in ret.iter_mut().zip(&r) {
                        *s += f64::from(*x);
                    }
                    if out.done() {
                        break;
                    }
                }
                let dist = (0..k)
                    .map(|m| env.distance_to_target(m).expect("mode"))
                    .collect();
                (ret, dist)
            })
            .collect()
    }

    fn expert(mode: usize) -> impl FnMut(&Reacher, &mut ChaCha8Rng) -> [f32; 2] {
        move |env, rng| {
            let mut a = [0.0; 2];
            env.expert_action(mode, rng, &mut a).expect("expert");
            a
        }
    }

    fn random(_: &Reacher, rng: &mut ChaCha8Rng) -> [f32; 2] {
        [rng.random_range(-1.0..=1.0), rng.random_range(-1.0..=1.0)]
    }

    #[test]
    fn the_model_has_the_standard_reacher_timing_and_episode_length() {
        let env = env(6);
        assert!((env.timestep() - 0.01).abs() < 1e-12);
        assert_eq!(env.config().frame_skip, 2);
        assert_eq!(env.spec().max_steps, 50);
        assert_eq!((env.spec().obs_dim, env.spec().act_dim), (8, 2));
    }

    #[test]
    fn the_fingertip_is_where_forward_kinematics_puts_it() {
        let mut env = env(4);
        let mut obs = [0.0; Reacher::OBS_DIM];
        for seed in 0..5 {
            env.reset(seed, &mut obs).expect("reset");
            let [q0, q1] = env.joint_angles();
            let want = [
                LINK0 * q0.cos() + LINK1 * (q0 + q1).cos(),
                LINK0 * q0.sin() + LINK1 * (q0 + q1).sin(),
            ];
            let p = env.fingertip();
            assert!((p[0] - want[0]).abs() < 1e-9 && (p[1] - want[1]).abs() < 1e-9);
            assert!((f64::from(obs[6]) - p[0]).abs() < 1e-6);
            assert!((f64::from(obs[7]) - p[1]).abs() < 1e-6);
        }
    }

    #[test]
    fn observation_holds_cosines_sines_velocities_and_fingertip() {
        let mut env = env(3);
        let mut obs = [0.0; Reacher::OBS_DIM];
        env.reset(9, &mut obs).expect("reset");
        env.step(&[0.5, -0.3], &mut obs).expect("step");
        let [q0, q1] = env.joint_angles();
        let [v0, v1] = env.joint_velocities();
        let p = env.fingertip();
        let want = [q0.cos(), q1.cos(), q0.sin(), q1.sin(), v0, v1, p[0], p[1]];
        for (i, (o, w)) in obs.iter().zip(want).enumerate() {
            assert!((f64::from(*o) - w).abs() < 1e-6, "obs[{i}] = {o}, want {w}");
        }
        assert!(v0.abs() > 0.1, "the motor should move the shoulder: {v0}");
    }

    #[test]
    fn initial_state_follows_the_reset_distribution() {
        let mut env = env(2);
        let mut obs = [0.0; Reacher::OBS_DIM];
        let (mut min0, mut max0) = (f64::MAX, f64::MIN);
        for seed in 0..200 {
            env.reset(seed, &mut obs).expect("reset");
            let [q0, q1] = env.joint_angles();
            let [v0, v1] = env.joint_velocities();
            assert!((-PI..=PI).contains(&q0) && (-PI / 2.0..=PI / 2.0).contains(&q1));
            assert!(v0.abs() <= 0.005 && v1.abs() <= 0.005);
            min0 = min0.min(q0);
            max0 = max0.max(q0);
        }
        assert!(min0 < -2.5 && max0 > 2.5, "{min0} {max0}");
    }

    #[test]
    fn targets_lie_evenly_on_a_reachable_circle() {
        for k in 2..=12 {
            let env = env(k);
            for m in 0..k {
                let t = env.target(m).expect("target");
                assert!((t[0].hypot(t[1]) - 0.15).abs() < 1e-12);
                let next = env.target((m + 1) % k).expect("target");
                let gap = (t[0] - next[0]).hypot(t[1] - next[1]);
                assert!((gap - 2.0 * 0.15 * (PI / k as f64).sin()).abs() < 1e-9);
            }
            assert!(env.target(k).is_none());
        }
    }

    #[test]
    fn mode_rewards_are_minus_distance_minus_the_control_cost() {
        let mut env = env(5);
        let mut obs = [0.0; Reacher::OBS_DIM];
        env.reset(4, &mut obs).expect("reset");
        let mut r = [0.0f32; 5];
        env.mode_rewards(&mut r);
        for (m, x) in r.iter().enumerate() {
            let d = env.distance_to_target(m).expect("mode");
            assert!((f64::from(*x) + d).abs() < 1e-6, "start state, mode {m}");
        }
        env.step(&[2.0, -0.5], &mut obs).expect("step");
        env.mode_rewards(&mut r);
        for (m, x) in r.iter().enumerate() {
            let d = env.distance_to_target(m).expect("mode");
            let want = -d - 0.1 * (1.0 + 0.25);
            assert!(
                (f64::from(*x) - want).abs() < 1e-6,
                "mode {m}: {x} vs {want}"
            );
        }
    }

    #[test]
    fn n_modes_out_of_range_is_an_error_naming_it() {
        for k in [0, 1, 13, 100] {
            let err = Reacher::new(ReacherConfig {
                n_modes: k,
                ..Default::default()
            })
            .expect_err("bad n_modes");
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

    #[test]
    fn invalid_config_errors_name_the_field() {
        assert_bad_params::<ReacherConfig, _>(
            Reacher::new,
            &[
                ("target_radius", |c| c.target_radius = 0.25),
                ("target_radius", |c| c.target_radius = f64::NAN),
                ("max_steps", |c| c.max_steps = 0),
                ("frame_skip", |c| c.frame_skip = 0),
                ("expert_noise", |c| c.expert_noise = -0.1),
            ],
        );
    }

    #[test]
    fn a_malformed_mjcf_string_is_a_clear_model_error() {
        assert_malformed_mjcf(|xml| Reacher::from_mjcf(xml, ReacherConfig::default()));
    }

    #[test]
    fn an_mjcf_of_the_wrong_shape_is_a_model_error_saying_what_is_wrong() {
        assert_wrong_shape_mjcf(
            |xml| Reacher::from_mjcf(xml, ReacherConfig::default()),
            &[
                (
                    REACHER_MJCF.replace("name=\"fingertip\"", "name=\"tip\""),
                    "fingertip",
                ),
                (
                    REACHER_MJCF.replace("<motor name=\"elbow_motor\" joint=\"elbow\"/>", ""),
                    "nu = 1",
                ),
            ],
        );
    }

    #[test]
    fn random_controls_over_twenty_episodes_raise_no_mujoco_warning() {
        let mut env = env(6);
        let mut obs = [0.0; Reacher::OBS_DIM];
        let mut top_speed = 0.0f64;
        for ep in 0..20 {
            let mut rng = ChaCha8Rng::seed_from_u64(ep);
            env.reset(ep, &mut obs).expect("reset");
            loop {
                // Saturated (bang-bang) and uniform controls, alternating by episode.
                let a = if ep % 2 == 0 {
                    random(&env, &mut rng)
                } else {
                    [
                        if rng.random::<bool>() { 1.0 } else { -1.0 },
                        if rng.random::<bool>() { 1.0 } else { -1.0 },
                    ]
                };
                let out = env.step(&a, &mut obs).expect("step raises no warning");
                assert!(obs.iter().all(|x| x.is_finite()));
                let [v0, v1] = env.joint_velocities();
                top_speed = top_speed.max(v0.abs()).max(v1.abs());
                if out.done() {
                    break;
                }
            }
            let warnings = env.warning_counts();
            assert!(
                warnings.iter().all(|&n| n == 0),
                "episode {ep}: {warnings:?}"
            );
        }
        assert!(top_speed < 200.0, "joint speed {top_speed} rad/s");
    }

    #[test]
    fn an_unstable_model_fails_loudly_instead_of_resetting() {
        // No armature, no damping and a huge gear: the state diverges within the episode.
        let unstable = REACHER_MJCF
            .replace(
                "armature=\"1\" damping=\"1\"",
                "armature=\"0\" damping=\"0\"",
            )
            .replace("gear=\"200\"", "gear=\"1e9\"");
        let mut env = Reacher::from_mjcf(&unstable, ReacherConfig::default()).expect("env");
        let mut obs = [0.0; Reacher::OBS_DIM];
        env.reset(0, &mut obs).expect("reset");
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let err = loop {
            match env.step(&random(&env, &mut rng), &mut obs) {
                Ok(out) => assert!(!out.done(), "the unstable model finished cleanly"),
                Err(e) => break e,
            }
        };
        assert!(matches!(err, EnvError::Simulation { .. }), "{err}");
        // The failed episode is over.
        let err = env.step(&[0.0, 0.0], &mut obs).unwrap_err();
        assert!(matches!(err, EnvError::StepAfterDone { .. }), "{err}");
    }

    #[test]
    fn inverse_kinematics_reaches_each_target_with_either_elbow() {
        let env = env(12);
        for m in 0..12 {
            let t = env.target(m).expect("target");
            for sign in [1.0, -1.0] {
                let [q0, q1] = inverse_kinematics(t, sign);
                let p = [
                    LINK0 * q0.cos() + LINK1 * (q0 + q1).cos(),
                    LINK0 * q0.sin() + LINK1 * (q0 + q1).sin(),
                ];
                assert!((p[0] - t[0]).hypot(p[1] - t[1]) < 1e-12, "mode {m}");
                assert!(q1 * sign >= 0.0);
            }
        }
    }

    #[test]
    fn the_expert_reaches_each_of_six_targets() {
        let mut env = env(6);
        for mode in 0..6 {
            let eps = run(&mut env, 10, expert(mode));
            let dists: Vec<f64> = eps.iter().map(|(_, d)| d[mode]).collect();
            let mean = dists.iter().sum::<f64>() / dists.len() as f64;
            let close = dists.iter().filter(|&&d| d < 0.02).count();
            assert!(mean < 0.03, "mode {mode}: final distances {dists:?}");
            assert!(close >= 8, "mode {mode}: final distances {dists:?}");
        }
    }

    #[test]
    fn the_expert_beats_a_random_policy_by_a_wide_margin_on_its_mode() {
        let mut env = env(6);
        let rand_eps = run(&mut env, 10, random);
        for mode in 0..6 {
            let ex: f64 = run(&mut env, 10, expert(mode))
                .iter()
                .map(|(r, _)| r[mode])
                .sum::<f64>()
                / 10.0;
            let rd: f64 = rand_eps.iter().map(|(r, _)| r[mode]).sum::<f64>() / 10.0;
            assert!(ex > rd + 5.0, "mode {mode}: expert {ex}, random {rd}");
        }
    }

    #[test]
    fn the_expert_reaches_its_own_target_not_the_others() {
        let mut env = env(6);
        for mode in 0..6 {
            let eps = run(&mut env, 5, expert(mode));
            for (_, d) in &eps {
                for other in (0..6).filter(|&o| o != mode) {
                    assert!(d[other] > d[mode] + 0.1, "mode {mode}: {d:?}");
                }
            }
        }
    }

    #[test]
    fn expert_is_deterministic_given_its_rng() {
        let mut env = env(4);
        let a = run(&mut env, 2, expert(1));
        let b = run(&mut env, 2, expert(1));
        assert_eq!(a, b);
    }

    #[test]
    fn demonstrations_can_be_generated_from_the_reacher_expert() {
        let spec = crate::DemoSpec {
            env: "reacher".into(),
            n_modes: 4,
            label_ratio: 0.1,
            imbalance_ratio: 10.0,
            majority_episodes: 4,
            seed: 3,
        };
        let demos = crate::generate_demos(&spec).expect("generate");
        let n = demos.unlabeled.len();
        assert!(n > 0 && n.is_multiple_of(50), "{n} steps");
        assert_eq!(demos.unlabeled.obs.len(), n * Reacher::OBS_DIM);
        assert_eq!(demos.unlabeled.act.len(), n * Reacher::ACT_DIM);
        assert!(demos.unlabeled.act.iter().all(|a| a.abs() < 1.0));
        assert!(!demos.labeled.mode.is_empty());
    }

    #[test]
    fn wrap_angle_maps_into_minus_pi_to_pi() {
        for a in [-7.0, -PI, -1.0, 0.0, 1.0, PI, 4.0, 10.0] {
            let w = wrap_angle(a);
            assert!(w > -PI - 1e-12 && w <= PI + 1e-12, "{a} -> {w}");
        }
    }
}
