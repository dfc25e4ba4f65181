//! The 2D trajectory task (paper Sec. 4 "Task setup (1)", Fig. 1; InfoGAIL's 2D
//! experiment).
//!
//! The agent moves in the plane at a constant `speed` per step. Its state is the
//! position `p` and the heading `theta`; the 1-D action `a` in `[-1, 1]` turns the
//! heading by `a * max_turn`, then `p += speed * (cos theta, sin theta)`.
//!
//! The observation is the last five positions, oldest first:
//! `[x_{t-4}, y_{t-4}, ..., x_t, y_t]` (10 floats); before the episode start the
//! history holds the start position. Episodes start at the origin with heading
//! `U(-heading_noise, heading_noise)` (deterministic given the reset seed), last
//! `max_steps` steps and end truncated, never terminated.
//!
//! Four behaviour modes, all circles through the origin (tangent to the x axis there):
//!
//! | mode | centre          | radius    | direction       |
//! |------|-----------------|-----------|-----------------|
//! | 0    | `(0, +r_small)` | `r_small` | counter-clockwise (left turns) |
//! | 1    | `(0, -r_small)` | `r_small` | clockwise (right turns)        |
//! | 2    | `(0, +r_large)` | `r_large` | counter-clockwise              |
//! | 3    | `(0, -r_large)` | `r_large` | clockwise                      |
//!
//! The evaluation reward of mode `k` is `-| |p - c_k| - R_k |` with `p` after the step.
//!
//! The scripted expert of mode `k` steers toward a desired heading: the circle's
//! tangent at the agent's angular position, tilted inward by `atan(radial_gain * e)`
//! where `e` is the radial error. Its turn is the nominal `±speed / R_k` plus
//! `heading_gain` times the heading error, in action units (divided by `max_turn`),
//! plus Gaussian noise of standard deviation `expert_noise` (action units), clamped to
//! `[-0.999, 0.999]` (strictly inside the tanh-squashed policy's range).
//!
//! Deviation from the brief: no per-episode style jitter. [`ScriptedExpert::expert_action`]
//! takes `&self`, so per-episode expert state would need to live in the env; the
//! Gaussian noise already makes the expert stochastic.

use std::f64::consts::PI;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::env::{
    Build, Env, EnvEntry, EnvError, EnvSpec, ScriptedExpert, StateReader, StateWriter, StepOutcome,
    check_action, check_can_step, check_obs_len,
};

/// Number of positions in an observation.
const HISTORY: usize = 5;

/// Largest magnitude of an expert action.
const EXPERT_ACTION_LIMIT: f64 = 0.999;

/// Parameters of [`Traj2D`]. Defaults: the large circle is completed about once per
/// episode (`2 pi r_large ~= speed * max_steps`), the small one twice; expert actions
/// are about `±0.5` (small circles) and `±0.25` (large circles).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Traj2DConfig {
    /// Distance travelled per step.
    pub speed: f64,
    /// Heading change (radians) per step for action 1.0.
    pub max_turn: f64,
    /// Radius of the small circles (modes 0 and 1).
    pub r_small: f64,
    /// Radius of the large circles (modes 2 and 3).
    pub r_large: f64,
    /// Episode length in steps.
    pub max_steps: usize,
    /// Standard deviation of the expert's Gaussian action noise, in action units.
    pub expert_noise: f64,
    /// Half-width of the uniform start-heading noise, in radians.
    pub heading_noise: f64,
    /// Expert gain from radial error to inward heading tilt (`atan(gain * e)`).
    pub radial_gain: f64,
    /// Expert gain from heading error (radians) to turn (radians).
    pub heading_gain: f64,
}

impl Default for Traj2DConfig {
    fn default() -> Self {
        Self {
            speed: 0.125,
            max_turn: 0.25,
            r_small: 1.0,
            r_large: 2.0,
            max_steps: 100,
            expert_noise: 0.05,
            heading_noise: 0.05,
            radial_gain: 2.0,
            heading_gain: 0.5,
        }
    }
}

impl Traj2DConfig {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), EnvError> {
        let positive = [
            ("speed", self.speed),
            ("max_turn", self.max_turn),
            ("r_small", self.r_small),
            ("r_large", self.r_large),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(bad(field, value, "must be positive and finite"));
            }
        }
        let non_negative = [
            ("expert_noise", self.expert_noise),
            ("heading_noise", self.heading_noise),
            ("radial_gain", self.radial_gain),
            ("heading_gain", self.heading_gain),
        ];
        for (field, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                return Err(bad(field, value, "must be non-negative and finite"));
            }
        }
        if self.max_steps == 0 {
            return Err(EnvError::BadParam {
                field: "max_steps",
                value: "0".into(),
                reason: "must be at least 1".into(),
            });
        }
        if self.r_large <= self.r_small {
            return Err(bad(
                "r_large",
                self.r_large,
                &format!("must be larger than r_small = {}", self.r_small),
            ));
        }
        if self.speed / self.r_small >= self.max_turn {
            return Err(bad(
                "max_turn",
                self.max_turn,
                &format!(
                    "must exceed speed / r_small = {} so the expert can follow the small circle",
                    self.speed / self.r_small
                ),
            ));
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

/// One circular behaviour mode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle {
    /// Centre of the circle.
    pub centre: [f64; 2],
    /// Radius.
    pub radius: f64,
    /// `+1.0` for counter-clockwise, `-1.0` for clockwise.
    pub direction: f64,
}

/// The 2D trajectory environment; see the module docs.
#[derive(Debug, Clone)]
pub struct Traj2D {
    cfg: Traj2DConfig,
    spec: EnvSpec,
    circles: [Circle; 4],
    pos: [f64; 2],
    heading: f64,
    /// Last `HISTORY` positions, oldest first.
    history: [[f64; 2]; HISTORY],
    steps: usize,
    started: bool,
    done: bool,
}

impl Traj2D {
    /// Number of behaviour modes.
    pub const N_MODES: usize = 4;
    /// Observation length.
    pub const OBS_DIM: usize = 2 * HISTORY;
    /// Action length.
    pub const ACT_DIM: usize = 1;

    /// Builds the env after validating `cfg`. Call [`Env::reset`] before stepping.
    pub fn new(cfg: Traj2DConfig) -> Result<Self, EnvError> {
        cfg.validate()?;
        let circle = |sign: f64, radius: f64| Circle {
            centre: [0.0, sign * radius],
            radius,
            direction: sign,
        };
        let circles = [
            circle(1.0, cfg.r_small),
            circle(-1.0, cfg.r_small),
            circle(1.0, cfg.r_large),
            circle(-1.0, cfg.r_large),
        ];
        let spec = EnvSpec {
            name: "traj2d".into(),
            obs_dim: Self::OBS_DIM,
            act_dim: Self::ACT_DIM,
            n_modes: Self::N_MODES,
            max_steps: cfg.max_steps,
        };
        Ok(Self {
            cfg,
            spec,
            circles,
            pos: [0.0; 2],
            heading: 0.0,
            history: [[0.0; 2]; HISTORY],
            steps: 0,
            started: false,
            done: false,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &Traj2DConfig {
        &self.cfg
    }

    /// The circle of `mode`, or `None` when out of range.
    pub fn circle(&self, mode: usize) -> Option<Circle> {
        self.circles.get(mode).copied()
    }

    /// Current position.
    pub fn position(&self) -> [f64; 2] {
        self.pos
    }

    /// Current heading in radians.
    pub fn heading(&self) -> f64 {
        self.heading
    }

    /// Steps taken in the current episode.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Signed radial error `|p - c| - R` of the current position to `circle`.
    fn radial_error(&self, circle: &Circle) -> f64 {
        let dx = self.pos[0] - circle.centre[0];
        let dy = self.pos[1] - circle.centre[1];
        dx.hypot(dy) - circle.radius
    }

    fn write_obs(&self, obs: &mut [f32]) {
        for (slot, p) in obs.chunks_exact_mut(2).zip(&self.history) {
            slot[0] = p[0] as f32;
            slot[1] = p[1] as f32;
        }
    }
}

/// Wraps an angle into `(-pi, pi]`.
fn wrap_angle(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI { w - 2.0 * PI } else { w }
}

impl Env for Traj2D {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), EnvError> {
        check_obs_len(obs, Self::OBS_DIM)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let u: f64 = rng.random();
        self.heading = self.cfg.heading_noise * (2.0 * u - 1.0);
        self.pos = [0.0; 2];
        self.history = [self.pos; HISTORY];
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
        let a = f64::from(action[0]).clamp(-1.0, 1.0);
        self.heading = wrap_angle(self.heading + a * self.cfg.max_turn);
        self.pos[0] += self.cfg.speed * self.heading.cos();
        self.pos[1] += self.cfg.speed * self.heading.sin();
        self.history.rotate_left(1);
        self.history[HISTORY - 1] = self.pos;
        self.steps += 1;
        let truncated = self.steps >= self.cfg.max_steps;
        self.done = truncated;
        self.write_obs(obs);
        Ok(StepOutcome {
            terminated: false,
            truncated,
        })
    }

    fn mode_rewards(&self, out: &mut [f32]) {
        for (r, circle) in out.iter_mut().zip(&self.circles) {
            *r = -(self.radial_error(circle).abs() as f32);
        }
    }

    /// `[pos (2), heading, history (2 x HISTORY), steps, started, done]`.
    fn state(&self) -> Vec<f64> {
        StateWriter::default()
            .put(&self.pos)
            .put(&[self.heading])
            .put(self.history.as_flattened())
            .count(self.steps)
            .flag(self.started)
            .flag(self.done)
            .finish()
    }

    fn set_state(&mut self, state: &[f64]) -> Result<(), EnvError> {
        let mut r = StateReader::new(&self.spec.name, state, 3 + 2 * HISTORY + 3)?;
        let pos = [r.scalar(), r.scalar()];
        let heading = r.scalar();
        let hist = r.take(2 * HISTORY);
        let steps = r.count("steps", self.spec.max_steps)?;
        let started = r.flag("started")?;
        let done = r.flag("done")?;
        self.pos = pos;
        self.heading = heading;
        for (h, xy) in self.history.iter_mut().zip(hist.chunks_exact(2)) {
            *h = [xy[0], xy[1]];
        }
        self.steps = steps;
        self.started = started;
        self.done = done;
        Ok(())
    }
}

impl ScriptedExpert for Traj2D {
    fn expert_action(
        &self,
        mode: usize,
        rng: &mut ChaCha8Rng,
        action: &mut [f32],
    ) -> Result<(), EnvError> {
        let circle = self.circle(mode).ok_or(EnvError::ModeOutOfRange {
            mode,
            n_modes: Self::N_MODES,
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
        let s = circle.direction;
        let dx = self.pos[0] - circle.centre[0];
        let dy = self.pos[1] - circle.centre[1];
        let phi = dy.atan2(dx);
        let tangent = phi + s * PI / 2.0;
        // Outside the circle (e > 0) tilt toward the centre: left for CCW, right for CW.
        let e = self.radial_error(&circle);
        let desired = tangent + s * (self.cfg.radial_gain * e).atan();
        let heading_error = wrap_angle(desired - self.heading);
        let turn = s * self.cfg.speed / circle.radius + self.cfg.heading_gain * heading_error;
        let noise: f64 = rng.sample(StandardNormal);
        let a = turn / self.cfg.max_turn + self.cfg.expert_noise * noise;
        action[0] = a.clamp(-EXPERT_ACTION_LIMIT, EXPERT_ACTION_LIMIT) as f32;
        Ok(())
    }
}

/// The registry's entry ([`crate::registry`]): exactly [`Traj2D::N_MODES`] modes, with
/// scripted experts.
pub const ENTRY: EnvEntry = EnvEntry {
    name: "traj2d",
    build: Build::Scripted(|n_modes| {
        if n_modes != Traj2D::N_MODES {
            return Err(EnvError::BadParam {
                field: "n_modes",
                value: n_modes.to_string(),
                reason: format!("traj2d has exactly {} modes", Traj2D::N_MODES),
            });
        }
        Ok(Box::new(Traj2D::new(Traj2DConfig::default())?))
    }),
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::conformance::assert_bad_params;

    /// Mean per-step reward of every mode over `episodes` episodes, acting with `policy`.
    fn mean_mode_rewards(
        env: &mut Traj2D,
        episodes: u64,
        mut policy: impl FnMut(&Traj2D, &mut ChaCha8Rng) -> f32,
    ) -> [f64; 4] {
        let mut obs = [0.0; Traj2D::OBS_DIM];
        let mut r = [0.0f32; 4];
        let mut sum = [0.0f64; 4];
        let mut n = 0usize;
        for ep in 0..episodes {
            let mut rng = ChaCha8Rng::seed_from_u64(1000 + ep);
            env.reset(ep, &mut obs).expect("reset");
            loop {
                let a = policy(env, &mut rng);
                let out = env.step(&[a], &mut obs).expect("step");
                env.mode_rewards(&mut r);
                for (s, x) in sum.iter_mut().zip(r) {
                    *s += f64::from(x);
                }
                n += 1;
                if out.done() {
                    break;
                }
            }
        }
        sum.map(|s| s / n as f64)
    }

    fn expert(mode: usize) -> impl FnMut(&Traj2D, &mut ChaCha8Rng) -> f32 {
        move |env, rng| {
            let mut a = [0.0];
            env.expert_action(mode, rng, &mut a).expect("expert");
            a[0]
        }
    }

    #[test]
    fn default_config_is_valid_and_completes_the_large_circle_about_once() {
        let cfg = Traj2DConfig::default();
        cfg.validate().expect("valid");
        let laps = cfg.speed * cfg.max_steps as f64 / (2.0 * PI * cfg.r_large);
        assert!((0.9..1.1).contains(&laps), "{laps}");
    }

    #[test]
    fn invalid_config_errors_name_the_field() {
        assert_bad_params::<Traj2DConfig, _>(
            Traj2D::new,
            &[
                ("speed", |c| c.speed = -1.0),
                ("max_turn", |c| c.max_turn = f64::NAN),
                ("r_small", |c| c.r_small = 0.0),
                ("r_large", |c| c.r_large = 0.5),
                ("max_steps", |c| c.max_steps = 0),
                ("expert_noise", |c| c.expert_noise = f64::INFINITY),
                ("max_turn", |c| c.max_turn = 0.1),
            ],
        );
    }

    #[test]
    fn observation_is_the_last_five_positions_oldest_first() {
        let mut env = Traj2D::new(Traj2DConfig::default()).expect("env");
        let mut obs = [0.0; Traj2D::OBS_DIM];
        env.reset(5, &mut obs).expect("reset");
        assert_eq!(obs, [0.0; 10]);
        let mut positions = vec![[0.0f32; 2]; 4];
        for i in 0..7 {
            env.step(&[0.3 * (i as f32 % 3.0 - 1.0)], &mut obs)
                .expect("step");
            let p = env.position();
            positions.push([p[0] as f32, p[1] as f32]);
            let want: Vec<f32> = positions[positions.len() - 5..]
                .iter()
                .flatten()
                .copied()
                .collect();
            assert_eq!(obs.to_vec(), want, "step {i}");
        }
    }

    #[test]
    fn actions_turn_the_heading_and_are_clamped() {
        let cfg = Traj2DConfig {
            heading_noise: 0.0,
            ..Default::default()
        };
        let mut env = Traj2D::new(cfg.clone()).expect("env");
        let mut obs = [0.0; Traj2D::OBS_DIM];
        env.reset(0, &mut obs).expect("reset");
        env.step(&[5.0], &mut obs).expect("step");
        assert!((env.heading() - cfg.max_turn).abs() < 1e-12);
        let p = env.position();
        assert!((p[0] - cfg.speed * cfg.max_turn.cos()).abs() < 1e-12);
        assert!((p[1] - cfg.speed * cfg.max_turn.sin()).abs() < 1e-12);
    }

    #[test]
    fn reset_heading_noise_depends_on_the_seed_and_is_small() {
        let mut env = Traj2D::new(Traj2DConfig::default()).expect("env");
        let mut obs = [0.0; Traj2D::OBS_DIM];
        let mut headings = Vec::new();
        for seed in 0..20 {
            env.reset(seed, &mut obs).expect("reset");
            assert!(env.heading().abs() <= 0.05);
            headings.push(env.heading());
        }
        headings.dedup();
        assert!(headings.len() > 10);
    }

    #[test]
    fn expert_episodes_stay_close_to_their_circle() {
        let mut env = Traj2D::new(Traj2DConfig::default()).expect("env");
        for mode in 0..4 {
            let means = mean_mode_rewards(&mut env, 10, expert(mode));
            // mean |radial error| = -mean reward of the own mode.
            assert!(-means[mode] < 0.1, "mode {mode}: {means:?}");
        }
    }

    #[test]
    fn expert_actions_have_the_nominal_turn_magnitude() {
        let mut env = Traj2D::new(Traj2DConfig::default()).expect("env");
        let nominal = [0.5, -0.5, 0.25, -0.25];
        for (mode, want) in nominal.into_iter().enumerate() {
            let mut sum = 0.0;
            let mut n = 0;
            mean_mode_rewards(&mut env, 5, |env, rng| {
                let a = expert(mode)(env, rng);
                sum += f64::from(a);
                n += 1;
                a
            });
            let mean = sum / f64::from(n);
            assert!((mean - want).abs() < 0.1, "mode {mode}: {mean}");
        }
    }

    #[test]
    fn the_four_expert_modes_are_clearly_distinct() {
        let mut env = Traj2D::new(Traj2DConfig::default()).expect("env");
        for mode in 0..4 {
            let means = mean_mode_rewards(&mut env, 5, expert(mode));
            for other in (0..4).filter(|&o| o != mode) {
                assert!(
                    means[other] < means[mode] - 0.3,
                    "expert {mode} scores mode {other} too well: {means:?}"
                );
            }
        }
    }

    #[test]
    fn a_uniformly_random_policy_scores_far_below_the_expert_on_every_mode() {
        let mut env = Traj2D::new(Traj2DConfig::default()).expect("env");
        let random = mean_mode_rewards(&mut env, 20, |_, rng| rng.random_range(-1.0..=1.0));
        for mode in 0..4 {
            let ex = mean_mode_rewards(&mut env, 20, expert(mode));
            assert!(
                random[mode] < ex[mode] - 0.5,
                "mode {mode}: random {} expert {}",
                random[mode],
                ex[mode]
            );
        }
    }

    #[test]
    fn expert_is_deterministic_given_its_rng() {
        let mut env = Traj2D::new(Traj2DConfig::default()).expect("env");
        let a = mean_mode_rewards(&mut env, 2, expert(2));
        let b = mean_mode_rewards(&mut env, 2, expert(2));
        assert_eq!(a, b);
    }

    #[test]
    fn wrap_angle_maps_into_minus_pi_to_pi() {
        for a in [-7.0, -PI, -1.0, 0.0, 1.0, PI, 4.0, 10.0] {
            let w = wrap_angle(a);
            assert!(w > -PI - 1e-12 && w <= PI + 1e-12, "{a} -> {w}");
            assert!(((a - w) / (2.0 * PI)).round() * 2.0 * PI - (a - w) < 1e-9);
        }
    }
}
