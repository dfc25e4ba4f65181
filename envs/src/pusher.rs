//! Multi-goal Pusher on MuJoCo (paper Sec. 4 "Task setup (3)").
//!
//! A 7-DoF arm with the standard (Gymnasium) Pusher robot's dimensions pushes a puck
//! across a table (the paper's text says "4-DoF"; the standard Pusher arm, used here,
//! has seven joints). The MJCF ([`PUSHER_MJCF`]) is written for this crate:
//!
//! - joints, in `qpos` order: shoulder pan (about z, at [`SHOULDER`] `= (0, -0.6)`,
//!   height 0), shoulder lift (about y, 0.1 m out), upper-arm roll (about x), elbow
//!   flex (about y, 0.4 m further), forearm roll (about x), wrist flex (about y,
//!   0.321 m further), wrist roll (about x), then the puck's two slide joints (x, y);
//! - at the wrist a fork: a 0.2 m crossbar across the arm and two 0.1 m prongs
//!   forward (capsules of radius 0.02), the only arm geoms that collide. The body
//!   `tips_arm` sits at the crossbar's centre (where Gymnasium's `tips_arm` body
//!   origin is, which is what its observation reports);
//! - a puck (`object`): a cylinder of radius 0.05 m and height 0.1 m standing on the
//!   table (`z = -0.325`), centre height `z = -0.275`, of mass 0.01 kg, sliding on
//!   two damped slide joints; it collides with the fork only (the slide joints already
//!   hold it on the table, so table contacts would cost time and change nothing).
//!   Gymnasium's puck has a near-zero density (mass ~1e-8 kg); MuJoCo 3 scales a
//!   contact's regularisation by the bodies' inverse masses, so such a puck receives
//!   almost no contact force and cannot be pushed;
//! - no gravity, Euler integration with timestep 0.01 s, frame skip 5 (0.05 s per env
//!   step), joint armature 0.04 and Gymnasium's joint damping and ranges.
//!
//! **Actions.** Gymnasium's motors take torques in `[-2, 2]`; the Ess contract takes
//! actions in `[-1, 1]`, so each motor has gear 2 and `ctrlrange` `[-1, 1]`: action
//! `a` applies the torque `2 a`, exactly Gymnasium's torque for its action `2 a`.
//!
//! **Observation** (20 floats): Gymnasium Pusher-v5's without the goal,
//! `[qpos[0..7], qvel[0..7], tips_arm xyz, object xyz]`.
//!
//! **Behaviour modes.** `n_modes = K` goals (`2..=6`, default 6) lie evenly on an arc
//! of radius `goal_radius` (default 0.2 m) around the puck's nominal start
//! [`OBJECT_START`]: the arc spans `goal_arc` (default pi, endpoints included) and is
//! centred on the direction pointing away from the shoulder pan axis, so every goal is
//! in front of or beside the puck as seen from the arm and can be reached by pushing
//! (outward with the crossbar, sideways with a prong). Goal `k` is at angle
//! `-goal_arc / 2 + goal_arc * k / (K - 1)` from that direction (counter-clockwise
//! positive), at the puck's centre height. The goals are *not* in the observation, so
//! the behaviour mode is latent. (The paper only says "6 evenly distributed goal
//! positions"; this arc is our choice, checked by a scripted push to every goal in
//! the tests.)
//!
//! **Initial state**, deterministic given the reset seed: arm joints at zero (the arm
//! stretched out along +x, level with the shoulder; Gymnasium's start) plus
//! `U(-init_qpos_noise, init_qpos_noise)` each (default 0.02 rad) cut to the joint's
//! range (elbow flex and wrist flex, whose ranges end at 0, get `U(-noise, 0)`), arm
//! joint velocities `U(-init_qvel_noise, init_qvel_noise)` (default 0.005 rad/s,
//! Gymnasium's), and the puck at [`OBJECT_START`] plus
//! `U(-object_init_noise, object_init_noise)` in x and in y (default 0.03 m), at rest.
//!
//! **Rewards.** The evaluation reward of mode `k` is Gymnasium Pusher-v5's with goal
//! `k`, after the step:
//! `-|object - goal_k| - 0.1 |2 a|^2 - 0.5 |tips_arm - object|`, where `2 a` is the
//! applied torque (Gymnasium's action units; `a` is the clamped action, zero before the
//! first step). The task reward (what an expert of mode `k` is trained on) is the same
//! reward: Gymnasium's already shapes with the arm-to-puck term.
//!
//! Episodes last `max_steps` (default 100) steps and end truncated, never terminated.
//! A MuJoCo warning during a step (for example an unstable, diverging state, which
//! MuJoCo would silently reset) is an [`EnvError::Simulation`] error, never ignored.
//!
//! There is no scripted expert: Pusher's experts are trained (PPO) policies.

use std::f64::consts::PI;
use std::fmt;

use mujoco_rs::prelude::MjtObjBase;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::env::{
    Build, Env, EnvEntry, EnvError, EnvSpec, StepOutcome, check_action, check_can_step,
    check_obs_len,
};
use crate::mujoco::{self, model_error};

/// Number of arm joints (and motors).
pub const ARM_DOF: usize = 7;

/// Nominal start of the puck centre `(x, y)` on the table, in metres (the centre of
/// Gymnasium's start region); [`PusherConfig::object_init_noise`] jitters it.
pub const OBJECT_START: [f64; 2] = [0.3, -0.05];

/// Height of the puck's centre (and of every goal), in metres.
pub const OBJECT_Z: f64 = -0.275;

/// Position `(x, y)` of the shoulder pan axis; the goal arc faces away from it.
pub const SHOULDER: [f64; 2] = [0.0, -0.6];

/// Applied torque per unit of action (the motors' gear).
pub const TORQUE_PER_ACTION: f64 = 2.0;

/// Weight of the control cost `|torque|^2` (Gymnasium's `reward_control_weight`).
const CONTROL_COST: f64 = 0.1;

/// Weight of the fingertip-to-puck distance (Gymnasium's `reward_near_weight`).
const NEAR_WEIGHT: f64 = 0.5;

/// Weight of the puck-to-goal distance (Gymnasium's `reward_dist_weight`).
const DIST_WEIGHT: f64 = 1.0;

/// Name of the body at the fork's crossbar centre that the model must define.
const TIP_BODY: &str = "tips_arm";

/// Name of the puck body the model must define.
const OBJECT_BODY: &str = "object";

/// Names of the puck's slide joints, which must be the last two coordinates.
const OBJECT_JOINTS: [&str; 2] = ["object_x", "object_y"];

/// The Pusher model; see the module docs. Contact groups: table `2`, puck `1`, fork
/// `1 | 2` (the fork touches both, the puck never touches the table); the other arm
/// geoms do not collide.
pub const PUSHER_MJCF: &str = r#"<mujoco model="ess_pusher">
  <compiler angle="radian" inertiafromgeom="true" autolimits="true"/>
  <option timestep="0.01" integrator="Euler" gravity="0 0 0"/>
  <default>
    <joint type="hinge" armature="0.04" damping="0.1"/>
    <geom contype="0" conaffinity="0" condim="1" density="300" friction="0.8 0.1 0.1"
          margin="0.002"/>
    <motor gear="2" ctrlrange="-1 1"/>
    <default class="fork">
      <geom type="capsule" size="0.02" contype="3" conaffinity="3"/>
    </default>
  </default>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1"/>
    <geom name="table" type="plane" pos="0 0.5 -0.325" size="1 1 0.1" contype="2"
          conaffinity="2"/>
    <body name="shoulder_pan_link" pos="0 -0.6 0">
      <joint name="shoulder_pan" axis="0 0 1" range="-2.2854 1.714602" damping="1"/>
      <geom name="shoulder" type="capsule" fromto="0 0 -0.4 0 0 0.2" size="0.1"/>
      <body name="shoulder_lift_link" pos="0.1 0 0">
        <joint name="shoulder_lift" axis="0 1 0" range="-0.5236 1.3963" damping="1"/>
        <geom name="shoulder_lift_geom" type="capsule" fromto="0 -0.1 0 0 0.1 0" size="0.1"/>
        <body name="upper_arm_roll_link">
          <joint name="upper_arm_roll" axis="1 0 0" range="-1.5 1.7"/>
          <geom name="upper_arm_roll_geom" type="capsule" fromto="-0.1 0 0 0.1 0 0"
                size="0.02"/>
          <body name="upper_arm_link">
            <geom name="upper_arm" type="capsule" fromto="0 0 0 0.4 0 0" size="0.06"/>
            <body name="elbow_flex_link" pos="0.4 0 0">
              <joint name="elbow_flex" axis="0 1 0" range="-2.3213 0"/>
              <geom name="elbow" type="capsule" fromto="0 -0.02 0 0 0.02 0" size="0.06"/>
              <body name="forearm_roll_link">
                <joint name="forearm_roll" axis="1 0 0" range="-1.5 1.5"/>
                <geom name="forearm_roll_geom" type="capsule" fromto="-0.1 0 0 0.1 0 0"
                      size="0.02"/>
                <body name="forearm_link">
                  <geom name="forearm" type="capsule" fromto="0 0 0 0.291 0 0" size="0.05"/>
                  <body name="wrist_flex_link" pos="0.321 0 0">
                    <joint name="wrist_flex" axis="0 1 0" range="-1.094 0"/>
                    <geom name="wrist" type="capsule" fromto="0 -0.02 0 0 0.02 0" size="0.01"/>
                    <body name="wrist_roll_link">
                      <joint name="wrist_roll" axis="1 0 0" range="-1.5 1.5"/>
                      <geom name="crossbar" class="fork" fromto="0 -0.1 0 0 0.1 0"/>
                      <geom name="prong_right" class="fork" fromto="0 -0.1 0 0.1 -0.1 0"/>
                      <geom name="prong_left" class="fork" fromto="0 0.1 0 0.1 0.1 0"/>
                      <body name="tips_arm">
                        <geom name="tip_right" type="sphere" pos="0.1 -0.1 0" size="0.01"/>
                        <geom name="tip_left" type="sphere" pos="0.1 0.1 0" size="0.01"/>
                      </body>
                    </body>
                  </body>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
    <body name="object" pos="0.3 -0.05 -0.275">
      <joint name="object_x" type="slide" axis="1 0 0" damping="0.5"/>
      <joint name="object_y" type="slide" axis="0 1 0" damping="0.5"/>
      <geom name="puck" type="cylinder" size="0.05 0.05" mass="0.01" contype="1"
            conaffinity="1"/>
    </body>
  </worldbody>
  <actuator>
    <motor name="shoulder_pan_motor" joint="shoulder_pan"/>
    <motor name="shoulder_lift_motor" joint="shoulder_lift"/>
    <motor name="upper_arm_roll_motor" joint="upper_arm_roll"/>
    <motor name="elbow_flex_motor" joint="elbow_flex"/>
    <motor name="forearm_roll_motor" joint="forearm_roll"/>
    <motor name="wrist_flex_motor" joint="wrist_flex"/>
    <motor name="wrist_roll_motor" joint="wrist_roll"/>
  </actuator>
</mujoco>
"#;

/// Parameters of [`Pusher`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PusherConfig {
    /// Number of goals, one per behaviour mode (`2..=6`).
    pub n_modes: usize,
    /// Distance of every goal from [`OBJECT_START`], in metres (`0.1..=0.25`: at least
    /// a puck diameter, at most what the arm can push to).
    pub goal_radius: f64,
    /// Angle spanned by the goal arc, in radians (`(0, pi]`), endpoints included.
    pub goal_arc: f64,
    /// Episode length in env steps.
    pub max_steps: usize,
    /// Physics steps per env step.
    pub frame_skip: usize,
    /// Half-width of the uniform initial noise on each arm joint angle, in radians
    /// (`0..=0.1`).
    pub init_qpos_noise: f64,
    /// Half-width of the uniform initial noise on each arm joint velocity, in rad/s.
    pub init_qvel_noise: f64,
    /// Half-width of the uniform noise on the puck's start x and y, in metres
    /// (`0..=0.05`, so the start region stays clear of every goal).
    pub object_init_noise: f64,
}

impl Default for PusherConfig {
    fn default() -> Self {
        Self {
            n_modes: 6,
            goal_radius: 0.2,
            goal_arc: PI,
            max_steps: 100,
            frame_skip: 5,
            init_qpos_noise: 0.02,
            init_qvel_noise: 0.005,
            object_init_noise: 0.03,
        }
    }
}

impl PusherConfig {
    /// Smallest supported number of goals.
    pub const MIN_MODES: usize = 2;
    /// Largest supported number of goals.
    pub const MAX_MODES: usize = 6;

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), EnvError> {
        if !(Self::MIN_MODES..=Self::MAX_MODES).contains(&self.n_modes) {
            return Err(EnvError::BadParam {
                field: "n_modes",
                value: self.n_modes.to_string(),
                reason: format!(
                    "pusher supports {} to {} goals",
                    Self::MIN_MODES,
                    Self::MAX_MODES
                ),
            });
        }
        let ranges = [
            (
                "goal_radius",
                self.goal_radius,
                0.1,
                0.25,
                "must lie in [0.1, 0.25] m: beyond the puck's start, within the arm's push",
            ),
            (
                "init_qpos_noise",
                self.init_qpos_noise,
                0.0,
                0.1,
                "must lie in [0, 0.1] rad",
            ),
            (
                "init_qvel_noise",
                self.init_qvel_noise,
                0.0,
                1.0,
                "must lie in [0, 1] rad/s",
            ),
            (
                "object_init_noise",
                self.object_init_noise,
                0.0,
                0.05,
                "must lie in [0, 0.05] m so the start region stays clear of the goals",
            ),
        ];
        for (field, value, lo, hi, reason) in ranges {
            if !(value.is_finite() && (lo..=hi).contains(&value)) {
                return Err(bad(field, value, reason));
            }
        }
        if !(self.goal_arc.is_finite() && self.goal_arc > 0.0 && self.goal_arc <= PI) {
            return Err(bad(
                "goal_arc",
                self.goal_arc,
                "must lie in (0, pi] rad: the goals stay in front of or beside the puck",
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
        Ok(())
    }

    /// The goals `(x, y)` this configuration places (see the module docs), mode order.
    pub fn goals(&self) -> Vec<[f64; 2]> {
        let k = self.n_modes;
        let outward = (OBJECT_START[1] - SHOULDER[1]).atan2(OBJECT_START[0] - SHOULDER[0]);
        (0..k)
            .map(|i| {
                let frac = if k > 1 {
                    i as f64 / (k - 1) as f64
                } else {
                    0.5
                };
                let angle = outward - self.goal_arc / 2.0 + self.goal_arc * frac;
                [
                    OBJECT_START[0] + self.goal_radius * angle.cos(),
                    OBJECT_START[1] + self.goal_radius * angle.sin(),
                ]
            })
            .collect()
    }
}

fn bad(field: &'static str, value: f64, reason: &str) -> EnvError {
    EnvError::BadParam {
        field,
        value: value.to_string(),
        reason: reason.to_owned(),
    }
}

/// The multi-goal Pusher environment; see the module docs.
pub struct Pusher {
    cfg: PusherConfig,
    spec: EnvSpec,
    data: mujoco::Data,
    /// Body id of `tips_arm`.
    tip: usize,
    /// Body id of `object`.
    object: usize,
    /// Goals at the puck's centre height, mode order.
    goals: Vec<[f64; 3]>,
    /// Interval of each arm joint's initial angle: the noise window cut to its range.
    init_qpos_range: [[f64; 2]; ARM_DOF],
    /// Clamped action of the last step (zero before the first).
    last_action: [f64; ARM_DOF],
    steps: usize,
    started: bool,
    done: bool,
}

impl fmt::Debug for Pusher {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Pusher")
            .field("cfg", &self.cfg)
            .field("qpos", &self.data.qpos())
            .field("qvel", &self.data.qvel())
            .field("steps", &self.steps)
            .field("started", &self.started)
            .field("done", &self.done)
            .finish_non_exhaustive()
    }
}

impl Pusher {
    /// Observation length.
    pub const OBS_DIM: usize = 20;
    /// Action length.
    pub const ACT_DIM: usize = ARM_DOF;
    /// Offset of `tips_arm`'s xyz in the observation.
    pub const OBS_TIP: usize = 2 * ARM_DOF;
    /// Offset of the puck's xyz in the observation.
    pub const OBS_OBJECT: usize = 2 * ARM_DOF + 3;

    /// Builds the env on [`PUSHER_MJCF`] after validating `cfg`. Call [`Env::reset`]
    /// before stepping.
    pub fn new(cfg: PusherConfig) -> Result<Self, EnvError> {
        Self::from_mjcf(PUSHER_MJCF, cfg)
    }

    /// Builds the env on the MJCF model `xml`, which must have nine position and nine
    /// velocity coordinates (seven arm hinges, then the puck's slide joints `object_x`
    /// and `object_y`), seven actuators, and bodies named `tips_arm` and `object`. A
    /// model MuJoCo rejects, or one of another shape, is [`EnvError::Model`] saying what
    /// is wrong. The `object` body must sit at [`OBJECT_START`], height [`OBJECT_Z`].
    pub fn from_mjcf(xml: &str, cfg: PusherConfig) -> Result<Self, EnvError> {
        cfg.validate()?;
        let model = mujoco::load_model(xml)?;
        let shape = [
            ("nq", model.ffi().nq, ARM_DOF + 2),
            ("nv", model.ffi().nv, ARM_DOF + 2),
            ("nu", model.ffi().nu, ARM_DOF),
        ];
        for (what, got, want) in shape {
            if usize::try_from(got).ok() != Some(want) {
                return Err(model_error(format!(
                    "{what} = {got}, expected {want} (a 7-joint, 7-motor arm and a puck on \
                     two slide joints)"
                )));
            }
        }
        let body = |name: &str| {
            model
                .name_to_id(MjtObjBase::mjOBJ_BODY, name)
                .ok_or_else(|| model_error(format!("no body named {name:?}")))
        };
        let tip = body(TIP_BODY)?;
        let object = body(OBJECT_BODY)?;
        let start = [OBJECT_START[0], OBJECT_START[1], OBJECT_Z];
        let pos = model.body_pos()[object];
        if dist(pos, start) > 1e-9 {
            return Err(model_error(format!(
                "body {OBJECT_BODY:?} is at {pos:?}, expected {start:?} (the puck's nominal \
                 start, which the goals are placed around)"
            )));
        }
        for (i, name) in OBJECT_JOINTS.into_iter().enumerate() {
            let id = model
                .name_to_id(MjtObjBase::mjOBJ_JOINT, name)
                .ok_or_else(|| model_error(format!("no joint named {name:?}")))?;
            let adr = model.jnt_qposadr()[id];
            let want = ARM_DOF + i;
            if usize::try_from(adr).ok() != Some(want) {
                return Err(model_error(format!(
                    "joint {name:?} has qpos address {adr}, expected {want} (the puck's \
                     slide joints come after the arm's)"
                )));
            }
        }
        // nq == nv, so every joint is a hinge or slide and joint j is coordinate j.
        let n = cfg.init_qpos_noise;
        let mut init_qpos_range = [[-n, n]; ARM_DOF];
        for (j, r) in init_qpos_range.iter_mut().enumerate() {
            if model.jnt_limited()[j] {
                let [lo, hi] = model.jnt_range()[j];
                *r = [(-n).clamp(lo, hi), n.clamp(lo, hi)];
            }
        }
        let data = mujoco::new_data(model)?;
        let goals = cfg
            .goals()
            .into_iter()
            .map(|[x, y]| [x, y, OBJECT_Z])
            .collect();
        let spec = EnvSpec {
            name: "pusher".into(),
            obs_dim: Self::OBS_DIM,
            act_dim: Self::ACT_DIM,
            n_modes: cfg.n_modes,
            max_steps: cfg.max_steps,
        };
        Ok(Self {
            cfg,
            spec,
            data,
            tip,
            object,
            goals,
            init_qpos_range,
            last_action: [0.0; ARM_DOF],
            steps: 0,
            started: false,
            done: false,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &PusherConfig {
        &self.cfg
    }

    /// Goal of `mode` (at the puck's centre height), or `None` when out of range.
    pub fn goal(&self, mode: usize) -> Option<[f64; 3]> {
        self.goals.get(mode).copied()
    }

    /// Current position of the puck's centre.
    pub fn object_position(&self) -> [f64; 3] {
        self.data.xpos()[self.object]
    }

    /// Current position of `tips_arm`, the centre of the fork's crossbar.
    pub fn fingertip(&self) -> [f64; 3] {
        self.data.xpos()[self.tip]
    }

    /// Distance from the puck's centre to the goal of `mode`, or `None` when out of
    /// range.
    pub fn object_goal_distance(&self, mode: usize) -> Option<f64> {
        let g = self.goal(mode)?;
        Some(dist(self.object_position(), g))
    }

    /// Current arm joint angles, in `qpos` order.
    pub fn joint_angles(&self) -> [f64; ARM_DOF] {
        let mut q = [0.0; ARM_DOF];
        q.copy_from_slice(&self.data.qpos()[..ARM_DOF]);
        q
    }

    /// Current arm joint velocities, in `qvel` order.
    pub fn joint_velocities(&self) -> [f64; ARM_DOF] {
        let mut v = [0.0; ARM_DOF];
        v.copy_from_slice(&self.data.qvel()[..ARM_DOF]);
        v
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
        let q = &self.data.qpos()[..ARM_DOF];
        let v = &self.data.qvel()[..ARM_DOF];
        let (tip, object) = (self.fingertip(), self.object_position());
        let values = q.iter().chain(v).chain(&tip).chain(&object);
        for (o, x) in obs.iter_mut().zip(values) {
            *o = *x as f32;
        }
    }

    /// Moves the puck to `(x, y)` at rest and recomputes positions (test set-up).
    #[cfg(test)]
    fn place_object(&mut self, xy: [f64; 2]) {
        let q = self.data.qpos_mut();
        q[ARM_DOF] = xy[0] - OBJECT_START[0];
        q[ARM_DOF + 1] = xy[1] - OBJECT_START[1];
        self.data.qvel_mut()[ARM_DOF..].fill(0.0);
        self.data.forward();
    }
}

/// Euclidean distance of two points.
fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

impl Env for Pusher {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), EnvError> {
        check_obs_len(obs, Self::OBS_DIM)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.random::<f64>();
        let mut qpos = [0.0; ARM_DOF + 2];
        let mut qvel = [0.0; ARM_DOF + 2];
        for (q, [lo, hi]) in qpos.iter_mut().zip(self.init_qpos_range) {
            *q = uniform(lo, hi);
        }
        let n = self.cfg.init_qvel_noise;
        for v in &mut qvel[..ARM_DOF] {
            *v = uniform(-n, n);
        }
        // The puck's slide coordinates are offsets from its body position, OBJECT_START.
        let n = self.cfg.object_init_noise;
        for q in &mut qpos[ARM_DOF..] {
            *q = uniform(-n, n);
        }
        // mj_resetData also clears the warning counters.
        self.data.reset();
        self.data.qpos_mut().copy_from_slice(&qpos);
        self.data.qvel_mut().copy_from_slice(&qvel);
        self.data.forward();
        self.last_action = [0.0; ARM_DOF];
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
        for (slot, a) in self.last_action.iter_mut().zip(action) {
            *slot = f64::from(*a).clamp(-1.0, 1.0);
        }
        self.data.ctrl_mut().copy_from_slice(&self.last_action);
        for _ in 0..self.cfg.frame_skip {
            self.data.step();
        }
        // mj_step leaves body positions at the state before its last integration step.
        self.data.forward_kinematics();
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

    /// `[MuJoCo integration state, last action (7), steps, started, done]`.
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
        let object = self.object_position();
        let near = dist(self.fingertip(), object);
        let torque_sq: f64 = self
            .last_action
            .iter()
            .map(|a| (TORQUE_PER_ACTION * a).powi(2))
            .sum();
        let shared = -CONTROL_COST * torque_sq - NEAR_WEIGHT * near;
        for (r, g) in out.iter_mut().zip(&self.goals) {
            *r = (shared - DIST_WEIGHT * dist(object, *g)) as f32;
        }
    }
}

/// The registry's entry ([`crate::registry`]): `n_modes` goals, trained experts.
pub const ENTRY: EnvEntry = EnvEntry {
    name: "pusher",
    build: Build::Trained(|n_modes| {
        Ok(Box::new(Pusher::new(PusherConfig {
            n_modes,
            ..PusherConfig::default()
        })?))
    }),
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::conformance::{
        assert_bad_params, assert_malformed_mjcf, assert_wrong_shape_mjcf,
    };
    use rand_distr::StandardNormal;

    /// A kinematic pose of the fork: where the crossbar centre is, and its axes.
    struct ForkPose {
        centre: [f64; 3],
        /// Unit vector along the prongs (the fork's pushing direction).
        forward: [f64; 3],
        /// Unit vector along the crossbar.
        across: [f64; 3],
    }

    fn fork_pose(env: &mut Pusher, q: &[f64; ARM_DOF]) -> ForkPose {
        env.data.qpos_mut()[..ARM_DOF].copy_from_slice(q);
        env.data.forward_kinematics();
        let m = env.data.xmat()[env.tip];
        ForkPose {
            centre: env.fingertip(),
            forward: [m[0], m[3], m[6]],
            across: [m[1], m[4], m[7]],
        }
    }

    /// How far `q` is from putting the crossbar centre at `target` with the fork level
    /// and its prongs pointing along the horizontal unit vector `dir` (0 when met
    /// within tolerance).
    fn pose_cost(env: &mut Pusher, q: &[f64; ARM_DOF], target: [f64; 3], dir: [f64; 2]) -> f64 {
        let p = fork_pose(env, q);
        let along = p.forward[0] * dir[0] + p.forward[1] * dir[1];
        dist(p.centre, target)
            + 0.1 * (0.97 - along).max(0.0)
            + 0.1 * (p.forward[2].abs() - 0.15).max(0.0)
            + 0.1 * (p.across[2].abs() - 0.15).max(0.0)
    }

    /// Joint angles (within the joint ranges) near `start` that lower the
    /// [`pose_cost`] of `target` and `dir`, by hill climbing (random perturbations of
    /// shrinking scale from `scales`); returns the best angles and their cost.
    fn refine(
        env: &mut Pusher,
        start: [f64; ARM_DOF],
        target: [f64; 3],
        dir: [f64; 2],
        scales: &[f64],
        rng: &mut ChaCha8Rng,
    ) -> ([f64; ARM_DOF], f64) {
        let ranges: Vec<[f64; 2]> = env.data.model().jnt_range()[..ARM_DOF].to_vec();
        let mut best = (start, pose_cost(env, &start, target, dir));
        for &scale in scales {
            for _ in 0..300 {
                let mut q = best.0;
                for (x, r) in q.iter_mut().zip(&ranges) {
                    let n: f64 = rng.sample(StandardNormal);
                    *x = (*x + scale * n).clamp(r[0], r[1]);
                }
                let c = pose_cost(env, &q, target, dir);
                if c < best.1 {
                    best = (q, c);
                }
            }
        }
        best
    }

    /// Joint angles (within the joint ranges) that put the fork at `target` facing
    /// `dir` (see [`pose_cost`]): the best of random samples, then [`refine`]d.
    fn find_pose(
        env: &mut Pusher,
        target: [f64; 3],
        dir: [f64; 2],
        rng: &mut ChaCha8Rng,
    ) -> ([f64; ARM_DOF], f64) {
        let ranges: Vec<[f64; 2]> = env.data.model().jnt_range()[..ARM_DOF].to_vec();
        let mut best = ([0.0; ARM_DOF], f64::MAX);
        for _ in 0..4000 {
            let mut q = [0.0; ARM_DOF];
            for (x, r) in q.iter_mut().zip(&ranges) {
                *x = rng.random_range(r[0]..=r[1]);
            }
            let c = pose_cost(env, &q, target, dir);
            if c < best.1 {
                best = (q, c);
            }
        }
        refine(
            env,
            best.0,
            target,
            dir,
            &[0.3, 0.1, 0.03, 0.01, 0.003],
            rng,
        )
    }

    /// A joint-space path that pushes the puck from `start` toward `goal`:
    /// the fork above the puck's far side from the goal, lowered around it, then
    /// moved in 1 cm waypoints along the line to `goal` until the puck (0.07 m ahead
    /// of the crossbar centre) would be on it. Each waypoint refines the previous one,
    /// so the path is continuous.
    fn push_path(
        env: &mut Pusher,
        start: [f64; 3],
        goal: [f64; 3],
        seed: u64,
    ) -> Vec<[f64; ARM_DOF]> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let d = [goal[0] - start[0], goal[1] - start[1]];
        let len = d[0].hypot(d[1]);
        let dir = [d[0] / len, d[1] / len];
        let at = |s: f64, lift: f64| {
            [
                start[0] + s * dir[0],
                start[1] + s * dir[1],
                OBJECT_Z + lift,
            ]
        };
        let fine = [0.03, 0.01, 0.003];
        let (low, _) = find_pose(env, at(-0.1, 0.0), dir, &mut rng);
        let (high, _) = refine(env, low, at(-0.1, 0.2), dir, &fine, &mut rng);
        let mut path = vec![high, low];
        let n = ((len + 0.03) / 0.01).ceil() as usize;
        for i in 1..=n {
            let s = -0.1 + (len + 0.03) * i as f64 / n as f64;
            let prev = path[path.len() - 1];
            let (q, _) = refine(env, prev, at(s, 0.0), dir, &fine, &mut rng);
            path.push(q);
        }
        path
    }

    /// Rolls one episode of a joint-space PD controller tracking `path`: 40 steps to
    /// the first waypoint (above the puck), 15 to the second (around it), then one
    /// step per waypoint, holding the last.
    fn follow(env: &mut Pusher, seed: u64, path: &[[f64; ARM_DOF]]) {
        let mut obs = [0.0; Pusher::OBS_DIM];
        env.reset(seed, &mut obs).expect("reset");
        for t in 0.. {
            let i = match t {
                0..40 => 0,
                40..55 => 1,
                _ => (t - 53).min(path.len() - 1),
            };
            let q = env.joint_angles();
            let v = env.joint_velocities();
            let mut a = [0.0f32; ARM_DOF];
            for j in 0..ARM_DOF {
                a[j] = (3.0 * (path[i][j] - q[j]) - 0.3 * v[j]).clamp(-1.0, 1.0) as f32;
            }
            if env.step(&a, &mut obs).expect("step").done() {
                break;
            }
        }
    }

    fn env() -> Pusher {
        Pusher::new(PusherConfig::default()).expect("env")
    }

    fn random_action(rng: &mut ChaCha8Rng) -> [f32; ARM_DOF] {
        std::array::from_fn(|_| rng.random_range(-1.0..=1.0))
    }

    fn assert_close(got: f64, want: f64, tol: f64, what: &str) {
        assert!((got - want).abs() <= tol, "{what}: got {got}, want {want}");
    }

    #[test]
    fn pusher_passes_the_conformance_suite() {
        crate::env::conformance::check_env("pusher", &|| {
            Box::new(Pusher::new(PusherConfig::default()).expect("env"))
        });
        crate::env::conformance::check_env("pusher (2 goals)", &|| {
            Box::new(
                Pusher::new(PusherConfig {
                    n_modes: 2,
                    ..Default::default()
                })
                .expect("env"),
            )
        });
    }

    #[test]
    fn the_model_has_the_standard_pusher_timing_and_shape() {
        let env = env();
        assert_close(env.timestep(), 0.01, 1e-12, "timestep");
        assert_eq!(env.config().frame_skip, 5);
        let spec = env.spec();
        assert_eq!(
            (spec.obs_dim, spec.act_dim, spec.n_modes, spec.max_steps),
            (20, 7, 6, 100)
        );
        assert_eq!(spec.name, "pusher");
        let m = env.data.model();
        assert!(m.actuator_gear().iter().all(|g| g[0] == TORQUE_PER_ACTION));
        assert!(m.actuator_ctrlrange().iter().all(|r| *r == [-1.0, 1.0]));
    }

    #[test]
    fn the_arm_has_the_standard_pusher_dimensions() {
        // All joints at zero: the arm lies along +x from the shoulder, level with it;
        // the crossbar is 0.1 + 0.4 + 0.321 m out.
        let mut env = env();
        let p = fork_pose(&mut env, &[0.0; ARM_DOF]);
        let want = [SHOULDER[0] + 0.821, SHOULDER[1], 0.0];
        for (got, want) in p.centre.iter().zip(want) {
            assert_close(*got, want, 1e-9, "tips_arm");
        }
        assert_close(p.forward[0], 1.0, 1e-9, "fork direction");
        // A quarter turn of the shoulder lift points the arm straight down from the
        // lift joint, 0.1 m out from the pan axis.
        let mut q = [0.0; ARM_DOF];
        q[1] = PI / 2.0;
        let p = fork_pose(&mut env, &q);
        let want = [SHOULDER[0] + 0.1, SHOULDER[1], -0.721];
        for (got, want) in p.centre.iter().zip(want) {
            assert_close(*got, want, 1e-9, "tips_arm, arm down");
        }
        // The fork: crossbar across the arm, prongs 0.1 m forward, 0.2 m apart.
        let m = env.data.model();
        let id = |n: &str| m.name_to_id(MjtObjBase::mjOBJ_GEOM, n).expect("geom");
        for (name, half_len) in [
            ("crossbar", 0.1),
            ("prong_left", 0.05),
            ("prong_right", 0.05),
        ] {
            assert_eq!(m.geom_size()[id(name)][..2], [0.02, half_len], "{name}");
        }
    }

    #[test]
    fn observation_holds_joints_velocities_fingertip_and_object() {
        let mut env = env();
        let mut obs = [0.0; Pusher::OBS_DIM];
        env.reset(5, &mut obs).expect("reset");
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for _ in 0..3 {
            env.step(&random_action(&mut rng), &mut obs).expect("step");
        }
        let q = env.joint_angles();
        let v = env.joint_velocities();
        let (tip, object) = (env.fingertip(), env.object_position());
        let want: Vec<f64> = q
            .iter()
            .chain(&v)
            .chain(&tip)
            .chain(&object)
            .copied()
            .collect();
        for (i, (o, w)) in obs.iter().zip(&want).enumerate() {
            assert_close(f64::from(*o), *w, 1e-6, &format!("obs[{i}]"));
        }
        let tip_slice = &obs[Pusher::OBS_TIP..Pusher::OBS_TIP + 3];
        let obj_slice = &obs[Pusher::OBS_OBJECT..Pusher::OBS_OBJECT + 3];
        for i in 0..3 {
            assert_close(f64::from(tip_slice[i]), tip[i], 1e-6, "tip slice");
            assert_close(f64::from(obj_slice[i]), object[i], 1e-6, "object slice");
        }
        assert!(
            v.iter().any(|x| x.abs() > 0.1),
            "the motors move the arm: {v:?}"
        );
        // The observation has no goal in it: it is the same for every n_modes.
        let mut two = Pusher::new(PusherConfig {
            n_modes: 2,
            ..Default::default()
        })
        .expect("env");
        let mut obs2 = [0.0; Pusher::OBS_DIM];
        two.reset(5, &mut obs2).expect("reset");
        let mut first = [0.0; Pusher::OBS_DIM];
        env.reset(5, &mut first).expect("reset");
        assert_eq!(first, obs2);
    }

    #[test]
    fn initial_state_follows_the_reset_distribution() {
        let mut env = env();
        let mut obs = [0.0; Pusher::OBS_DIM];
        let ranges: Vec<[f64; 2]> = env.data.model().jnt_range()[..ARM_DOF].to_vec();
        let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
        for seed in 0..200 {
            env.reset(seed, &mut obs).expect("reset");
            for (j, (q, v)) in env
                .joint_angles()
                .iter()
                .zip(env.joint_velocities())
                .enumerate()
            {
                assert!(q.abs() <= 0.02 && v.abs() <= 0.005, "joint {j}: {q} {v}");
                assert!(*q >= ranges[j][0] && *q <= ranges[j][1], "joint {j}: {q}");
            }
            let o = env.object_position();
            for i in 0..2 {
                let off = o[i] - OBJECT_START[i];
                assert!(off.abs() <= 0.03, "object offset {off}");
                lo[i] = lo[i].min(off);
                hi[i] = hi[i].max(off);
            }
            assert_close(o[2], OBJECT_Z, 1e-12, "object height");
            assert!(env.data.qvel()[ARM_DOF..].iter().all(|v| *v == 0.0));
        }
        for i in 0..2 {
            assert!(lo[i] < -0.025 && hi[i] > 0.025, "{lo:?} {hi:?}");
        }
    }

    #[test]
    fn goals_lie_evenly_on_an_arc_facing_away_from_the_shoulder() {
        for k in PusherConfig::MIN_MODES..=PusherConfig::MAX_MODES {
            let env = Pusher::new(PusherConfig {
                n_modes: k,
                ..Default::default()
            })
            .expect("env");
            let outward = [OBJECT_START[0] - SHOULDER[0], OBJECT_START[1] - SHOULDER[1]];
            let n = outward[0].hypot(outward[1]);
            let gap = 2.0 * 0.2 * (PI / 2.0 / (k - 1) as f64).sin();
            for m in 0..k {
                let g = env.goal(m).expect("goal");
                let d = [g[0] - OBJECT_START[0], g[1] - OBJECT_START[1]];
                assert_close(d[0].hypot(d[1]), 0.2, 1e-12, "goal radius");
                assert_close(g[2], OBJECT_Z, 0.0, "goal height");
                // Never behind the puck as seen from the shoulder.
                assert!(
                    (d[0] * outward[0] + d[1] * outward[1]) / n > -1e-9,
                    "goal {m}"
                );
                if m + 1 < k {
                    let next = env.goal(m + 1).expect("goal");
                    assert_close(dist(g, next), gap, 1e-9, "gap between goals");
                }
            }
            assert!(env.goal(k).is_none());
            assert!(env.object_goal_distance(k).is_none());
        }
    }

    #[test]
    fn mode_rewards_are_gymnasiums_pusher_reward_per_goal() {
        let mut env = env();
        let mut obs = [0.0; Pusher::OBS_DIM];
        env.reset(4, &mut obs).expect("reset");
        let mut r = [0.0f32; 6];
        let mut t = [0.0f32; 6];
        let check = |env: &Pusher, r: &[f32], ctrl: f64| {
            let near = dist(env.fingertip(), env.object_position());
            for (m, x) in r.iter().enumerate() {
                let d = env.object_goal_distance(m).expect("mode");
                let want = -d - ctrl - 0.5 * near;
                assert_close(f64::from(*x), want, 1e-5, &format!("mode {m}"));
            }
        };
        // The start state: no control cost yet.
        env.mode_rewards(&mut r);
        check(&env, &r, 0.0);
        // Torque = 2 * clamped action; the cost is 0.1 |torque|^2.
        let a = [2.0, -0.5, 0.0, 0.25, 0.0, -1.0, 0.1];
        env.step(&a, &mut obs).expect("step");
        env.mode_rewards(&mut r);
        let sq: f64 = [1.0f64, -0.5, 0.0, 0.25, 0.0, -1.0, 0.1]
            .iter()
            .map(|x| (2.0 * x).powi(2))
            .sum();
        check(&env, &r, 0.1 * sq);
        env.task_rewards(&mut t);
        assert_eq!(r, t, "the task reward is the evaluation reward");
        // A shorter buffer receives the first modes only.
        let mut short = [0.0f32; 2];
        env.mode_rewards(&mut short);
        assert_eq!(short, r[..2]);
    }

    #[test]
    fn the_reward_of_mode_k_is_highest_with_the_puck_on_goal_k() {
        let mut env = env();
        let mut obs = [0.0; Pusher::OBS_DIM];
        let mut r = [0.0f32; 6];
        env.reset(0, &mut obs).expect("reset");
        env.mode_rewards(&mut r);
        let at_start = r;
        for k in 0..6 {
            let g = env.goal(k).expect("goal");
            env.place_object([g[0], g[1]]);
            assert_close(
                env.object_goal_distance(k).expect("mode"),
                0.0,
                1e-9,
                "on goal",
            );
            env.mode_rewards(&mut r);
            let best = (0..6)
                .max_by(|&a, &b| r[a].total_cmp(&r[b]))
                .expect("modes");
            assert_eq!(best, k, "{r:?}");
            assert!(r[k] > at_start[k], "{r:?} vs {at_start:?}");
            for m in (0..6).filter(|&m| m != k) {
                assert!(r[k] > r[m] + 0.05, "mode {k} vs {m}: {r:?}");
            }
        }
    }

    #[test]
    fn a_scripted_push_moves_the_puck_to_each_goal_and_raises_its_reward() {
        let mut env = env();
        let mut r = [0.0f32; 6];
        for k in 0..6 {
            let g = env.goal(k).expect("goal");
            let mut obs = [0.0; Pusher::OBS_DIM];
            env.reset(k as u64, &mut obs).expect("reset");
            let start_dist = env.object_goal_distance(k).expect("mode");
            let start = env.object_position();
            let path = push_path(&mut env, start, g, k as u64);
            // Every step of the push succeeds, so MuJoCo raised no warning on contact.
            follow(&mut env, k as u64, &path);
            let dists: Vec<f64> = (0..6)
                .map(|m| env.object_goal_distance(m).expect("mode"))
                .collect();
            assert!(start_dist > 0.15, "goal {k}: start {start_dist}");
            assert!(dists[k] < 0.06, "goal {k}: final distances {dists:?}");
            env.mode_rewards(&mut r);
            for m in (0..6).filter(|&m| m != k) {
                assert!(dists[m] > dists[k] + 0.05, "goal {k}: {dists:?}");
                assert!(r[k] > r[m], "goal {k}: rewards {r:?}");
            }
            assert!(env.warning_counts().iter().all(|&n| n == 0));
        }
    }

    #[test]
    fn the_same_seed_replays_the_same_episode_and_rewards() {
        let run = |seed: u64| {
            let mut env = env();
            let mut obs = [0.0; Pusher::OBS_DIM];
            let mut r = [0.0f32; 6];
            let mut rng = ChaCha8Rng::seed_from_u64(seed + 100);
            env.reset(seed, &mut obs).expect("reset");
            let mut trace = obs.to_vec();
            loop {
                let out = env.step(&random_action(&mut rng), &mut obs).expect("step");
                env.mode_rewards(&mut r);
                trace.extend_from_slice(&obs);
                trace.extend_from_slice(&r);
                if out.done() {
                    break;
                }
            }
            trace
        };
        assert_eq!(run(3), run(3));
        assert_ne!(run(3), run(4));
    }

    #[test]
    fn random_controls_over_many_episodes_raise_no_mujoco_warning() {
        let mut env = env();
        let mut obs = [0.0; Pusher::OBS_DIM];
        let mut top_speed = 0.0f64;
        for ep in 0..30 {
            let mut rng = ChaCha8Rng::seed_from_u64(ep);
            env.reset(ep, &mut obs).expect("reset");
            loop {
                // Uniform and saturated (bang-bang) controls, alternating by episode.
                let mut a = random_action(&mut rng);
                if ep % 2 == 1 {
                    for x in &mut a {
                        *x = x.signum();
                    }
                }
                let out = env.step(&a, &mut obs).expect("step raises no warning");
                assert!(obs.iter().all(|x| x.is_finite()));
                top_speed = env
                    .joint_velocities()
                    .iter()
                    .fold(top_speed, |s, v| s.max(v.abs()));
                if out.done() {
                    assert_eq!(env.steps(), 100);
                    break;
                }
            }
            let warnings = env.warning_counts();
            assert!(
                warnings.iter().all(|&n| n == 0),
                "episode {ep}: {warnings:?}"
            );
        }
        assert!(top_speed < 50.0, "joint speed {top_speed} rad/s");
    }

    #[test]
    fn an_unstable_model_fails_loudly_instead_of_resetting() {
        let unstable = PUSHER_MJCF
            .replace(
                "armature=\"0.04\" damping=\"0.1\"",
                "armature=\"0\" damping=\"0\"",
            )
            .replace("damping=\"1\"", "damping=\"0\"")
            .replace("<motor gear=\"2\"", "<motor gear=\"1e12\"");
        let mut env = Pusher::from_mjcf(&unstable, PusherConfig::default()).expect("env");
        let mut obs = [0.0; Pusher::OBS_DIM];
        env.reset(0, &mut obs).expect("reset");
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let err = loop {
            match env.step(&random_action(&mut rng), &mut obs) {
                Ok(out) => assert!(!out.done(), "the unstable model finished cleanly"),
                Err(e) => break e,
            }
        };
        assert!(matches!(err, EnvError::Simulation { .. }), "{err}");
        let err = env.step(&[0.0; ARM_DOF], &mut obs).unwrap_err();
        assert!(matches!(err, EnvError::StepAfterDone { .. }), "{err}");
    }

    #[test]
    fn invalid_config_errors_name_the_field() {
        assert_bad_params::<PusherConfig, _>(
            Pusher::new,
            &[
                ("n_modes", |c| c.n_modes = 1),
                ("n_modes", |c| c.n_modes = 7),
                ("goal_radius", |c| c.goal_radius = 0.3),
                ("goal_radius", |c| c.goal_radius = 0.05),
                ("goal_radius", |c| c.goal_radius = f64::NAN),
                ("goal_arc", |c| c.goal_arc = 0.0),
                ("goal_arc", |c| c.goal_arc = 4.0),
                ("max_steps", |c| c.max_steps = 0),
                ("frame_skip", |c| c.frame_skip = 0),
                ("init_qpos_noise", |c| c.init_qpos_noise = -0.1),
                ("init_qvel_noise", |c| c.init_qvel_noise = f64::INFINITY),
                ("object_init_noise", |c| c.object_init_noise = 0.1),
            ],
        );
    }

    #[test]
    fn a_malformed_mjcf_string_is_a_clear_model_error() {
        assert_malformed_mjcf(|xml| Pusher::from_mjcf(xml, PusherConfig::default()));
    }

    #[test]
    fn an_mjcf_of_the_wrong_shape_is_a_model_error_saying_what_is_wrong() {
        let cases = [
            (
                PUSHER_MJCF.replace("<body name=\"tips_arm\">", "<body name=\"tip\">"),
                "no body named \"tips_arm\"",
            ),
            (
                PUSHER_MJCF.replace("<body name=\"object\"", "<body name=\"puck\""),
                "no body named \"object\"",
            ),
            (
                PUSHER_MJCF.replace(
                    "<motor name=\"wrist_roll_motor\" joint=\"wrist_roll\"/>",
                    "",
                ),
                "nu = 6",
            ),
            (
                PUSHER_MJCF.replace(
                    "<joint name=\"object_y\" type=\"slide\" axis=\"0 1 0\" damping=\"0.5\"/>",
                    "",
                ),
                "nq = 8",
            ),
            (
                PUSHER_MJCF.replace("name=\"object_y\"", "name=\"puck_y\""),
                "no joint named \"object_y\"",
            ),
            (
                PUSHER_MJCF
                    .replace("name=\"object_x\"", "name=\"tmp\"")
                    .replace("name=\"object_y\"", "name=\"object_x\"")
                    .replace("name=\"tmp\"", "name=\"object_y\""),
                "joint \"object_x\" has qpos address 8",
            ),
            (
                PUSHER_MJCF.replace("pos=\"0.3 -0.05 -0.275\"", "pos=\"0.3 0 -0.275\""),
                "body \"object\" is at",
            ),
        ];
        assert_wrong_shape_mjcf(
            |xml| Pusher::from_mjcf(xml, PusherConfig::default()),
            &cases,
        );
    }
}
