//! A task from the user's own MuJoCo model: a small TOML *task file* names the MJCF,
//! the observation, the actions, the episode and (optionally) per-mode evaluation
//! rewards. `make_plain_env("task:PATH.toml", k)` builds it, so it runs wherever a
//! built-in env runs (actor processes and threads, replay, resume).
//!
//! ```toml
//! mjcf = "arm3.xml"        # relative to this file; MuJoCo resolves its includes
//! frame_skip = 2           # physics steps per env step (default 1)
//! max_steps = 100          # the step reaching it is `truncated`
//! reset_noise = 0.01       # U(-x, x) on every qpos (around qpos0) and qvel entry
//!
//! [[obs]]                  # the observation, piece after piece
//! qpos = "*"               # all of qpos ...
//! drop = [0]               # ... but entry 0 (e.g. the root x); or take = [1, 2]
//! [[obs]]
//! qvel = "*"
//! clip = 10.0              # optional: clip each entry to [-10, 10]
//! [[obs]]
//! body_pos = "fingertip"   # also: qpos / qvel = "JOINT", sensor = "NAME" or "*",
//! take = [0, 1]            # body_vel = "BODY" (angular, linear: 6), body_quat = "BODY"
//!
//! [[terminate]]            # optional: terminated once a quantity leaves (lo, hi)
//! quantity = "body_pos.torso.z"
//! range = [0.8, 2.0]
//!
//! [[modes]]                # optional: one table per behaviour mode, in mode order
//! name = "left"
//! reward = [
//!   { distance = "fingertip", to = [-0.2, 0.1, 0.0], weight = -1.0 },
//!   { quantity = "ctrl_sq", weight = -0.01 },
//! ]
//! ```
//!
//! **Actions** are the model's actuators, in model order; every actuator needs a finite
//! `ctrlrange`, and an action in `[-1, 1]` is mapped linearly onto it (clamped first).
//!
//! **Quantities** (termination, reward terms) are scalars: `ctrl_sq` (the step's
//! `sum(ctrl^2)`), `qpos.JOINT[.i]`, `qvel.JOINT[.i]`, `sensor.NAME[.i]`,
//! `body_pos.BODY.x|y|z`, `body_vel.BODY.x|y|z` (linear) or `.wx|wy|wz` (angular),
//! `body_quat.BODY.w|x|y|z`. Every quantity and observation piece is read after
//! `mj_forward` on the state the step ends in, so positions, velocities and sensors
//! agree with each other.
//!
//! **Modes.** The number of behaviour modes comes from the demonstrations; when the
//! file has `[[modes]]`, their count must equal it and [`Env::mode_rewards`] scores
//! them (normalized reward then applies); without it the env has no evaluation reward
//! ([`Env::has_mode_rewards`] is false).
//!
//! Of the built-in tasks, Walker2d and Humanoid could be task files (their modes are
//! linear in `body_vel`-like quantities plus a healthy bonus, which a task file cannot
//! express yet); Traj2D (no physics) and Reacher / Pusher (a hidden target sampled per
//! episode) cannot.

mod file;
mod quantity;

use std::path::{Path, PathBuf};

pub use file::{ModeReward, ObsPiece, RewardTerm, TaskFile, Terminate};

use crate::env::{Env, EnvError, EnvSpec, StateReader, StateWriter, StepOutcome, check_obs_len};
use crate::locomotion::Sim;
use file::task_error;
use mujoco_rs::prelude::MjModel;
use quantity::{Scalar, Span, body_id, kept, resolve_scalar, resolve_span};

/// The prefix of a task file's env name: `task:PATH`.
pub const TASK_PREFIX: &str = "task:";

/// One observation piece, resolved.
#[derive(Debug, Clone)]
struct Piece {
    span: Span,
    keep: Vec<usize>,
    clip: Option<f64>,
}

/// A resolved reward term.
#[derive(Debug, Clone)]
enum Term {
    Quantity(Scalar),
    ToPoint(usize, [f64; 3]),
    ToBody(usize, usize),
}

/// An env built from a task file (see the module docs).
pub struct TaskEnv {
    spec: EnvSpec,
    sim: Sim,
    noise: f64,
    pieces: Vec<Piece>,
    terminate: Vec<(Scalar, [f64; 2])>,
    modes: Vec<Vec<(Term, f64)>>,
    /// Scratch for a piece's values.
    buf: Vec<f64>,
    /// The last step's `sum(ctrl^2)`.
    ctrl_sq: f64,
}

impl std::fmt::Debug for TaskEnv {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TaskEnv")
            .field("spec", &self.spec)
            .field("steps", &self.sim.steps)
            .finish_non_exhaustive()
    }
}

/// The task file path of an env name `task:PATH`, or `None` for other names.
pub fn task_path(env_name: &str) -> Option<&Path> {
    env_name.strip_prefix(TASK_PREFIX).map(Path::new)
}

impl TaskEnv {
    /// Loads the task file at `path` with `n_modes` behaviour modes; the env's name is
    /// `task:PATH` as given. Every error names the file and the key or piece.
    pub fn load(path: &Path, n_modes: usize) -> Result<Self, EnvError> {
        let file = TaskFile::read(path)?;
        if n_modes < 2 {
            return Err(task_error(
                path,
                format!("n_modes = {n_modes}: a task needs at least 2 behaviour modes"),
            ));
        }
        if !file.modes.is_empty() && file.modes.len() != n_modes {
            return Err(task_error(
                path,
                format!(
                    "modes: the file scores {} modes but the run has n_modes = {n_modes} \
                     (from the demonstrations)",
                    file.modes.len()
                ),
            ));
        }
        let mjcf = file.mjcf_path(path);
        let model = MjModel::from_xml(&mjcf).map_err(|e| {
            let msg = e.to_string().replace('\n', " ");
            task_error(
                path,
                format!("mjcf {}: MuJoCo: {}", mjcf.display(), msg.trim()),
            )
        })?;
        let at = |key: String| move |why: String| task_error(path, format!("{key}: {why}"));
        let pieces =
            resolve_pieces(&model, &file.obs).map_err(|(i, why)| at(format!("obs[{i}]"))(why))?;
        let mut terminate = Vec::new();
        for (i, t) in file.terminate.iter().enumerate() {
            let q = resolve_scalar(&model, &t.quantity).map_err(at(format!("terminate[{i}]")))?;
            terminate.push((q, t.range));
        }
        let mut modes = Vec::new();
        for (i, m) in file.modes.iter().enumerate() {
            let mut terms = Vec::new();
            for (j, t) in m.reward.iter().enumerate() {
                let term =
                    resolve_term(&model, t).map_err(at(format!("modes[{i}].reward[{j}]")))?;
                terms.push((term, t.weight));
            }
            modes.push(terms);
        }
        let sim = Sim::from_model(model, file.frame_skip, file.max_steps)
            .map_err(|e| task_error(path, format!("mjcf {}: {e}", mjcf.display())))?;
        let obs_dim = pieces.iter().map(|p| p.keep.len()).sum();
        let buf_len = pieces.iter().map(|p| p.span.len).max().unwrap_or(0);
        Ok(Self {
            spec: EnvSpec {
                name: format!("{TASK_PREFIX}{}", path.display()),
                obs_dim,
                act_dim: sim.n_actuators(),
                n_modes,
                max_steps: file.max_steps,
            },
            sim,
            noise: file.reset_noise,
            pieces,
            terminate,
            modes,
            buf: vec![0.0; buf_len],
            ctrl_sq: 0.0,
        })
    }

    fn write_obs(&mut self, obs: &mut [f32]) {
        let mut at = 0;
        for p in &self.pieces {
            let buf = &mut self.buf[..p.span.len];
            p.span.write(&self.sim.data, buf);
            for &i in &p.keep {
                let x = match p.clip {
                    Some(c) => buf[i].clamp(-c, c),
                    None => buf[i],
                };
                obs[at] = x as f32;
                at += 1;
            }
        }
    }

    fn terminated(&self) -> bool {
        self.terminate.iter().any(|(q, [lo, hi])| {
            let x = q.get(&self.sim.data, self.ctrl_sq);
            !(*lo < x && x < *hi)
        })
    }

    fn term(&self, t: &Term) -> f64 {
        let pos = |b: usize| self.sim.data.xpos()[b];
        let dist = |a: [f64; 3], b: [f64; 3]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y) * (x - y))
                .sum::<f64>()
                .sqrt()
        };
        match t {
            Term::Quantity(q) => q.get(&self.sim.data, self.ctrl_sq),
            Term::ToPoint(b, p) => dist(pos(*b), *p),
            Term::ToBody(a, b) => dist(pos(*a), pos(*b)),
        }
    }
}

fn resolve_pieces(model: &MjModel, obs: &[ObsPiece]) -> Result<Vec<Piece>, (usize, String)> {
    obs.iter()
        .enumerate()
        .map(|(i, p)| {
            let (key, name) = p.source().map_err(|e| (i, e))?;
            let span = resolve_span(model, key, name).map_err(|e| (i, e))?;
            let keep = kept(span.len, p.take.as_deref(), p.drop.as_deref())
                .map_err(|e| (i, format!("{key} = {name:?}: {e}")))?;
            Ok(Piece {
                span,
                keep,
                clip: p.clip,
            })
        })
        .collect()
}

fn resolve_term(model: &MjModel, t: &RewardTerm) -> Result<Term, String> {
    match (&t.quantity, &t.distance, &t.to, &t.to_body) {
        (Some(q), ..) => Ok(Term::Quantity(resolve_scalar(model, q)?)),
        (None, Some(b), Some(p), _) => Ok(Term::ToPoint(body_id(model, b)?, *p)),
        (None, Some(a), None, Some(b)) => Ok(Term::ToBody(body_id(model, a)?, body_id(model, b)?)),
        _ => Err("needs exactly one of quantity, distance".into()),
    }
}

impl Env for TaskEnv {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), EnvError> {
        check_obs_len(obs, self.spec.obs_dim)?;
        self.sim.reset(seed, self.noise);
        self.ctrl_sq = 0.0;
        self.write_obs(obs);
        Ok(())
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<StepOutcome, EnvError> {
        self.sim.check_step(action, obs, self.spec.obs_dim)?;
        self.ctrl_sq = self.sim.advance(action)?;
        self.sim.data.forward();
        let terminated = self.terminated();
        self.write_obs(obs);
        Ok(self.sim.finish(terminated))
    }

    fn mode_rewards(&self, out: &mut [f32]) {
        for (k, r) in out.iter_mut().enumerate() {
            *r = self.modes.get(k).map_or(0.0, |terms| {
                terms.iter().map(|(t, w)| w * self.term(t)).sum::<f64>() as f32
            });
        }
    }

    fn has_mode_rewards(&self) -> bool {
        !self.modes.is_empty()
    }

    fn scene(&self) -> Option<crate::scene::Scene> {
        Some(crate::mujoco::scene(&self.sim.data, self.sim.dt()))
    }

    fn body_poses(&self) -> Vec<crate::scene::Pose> {
        crate::mujoco::poses(&self.sim.data)
    }

    /// `[MuJoCo integration state, steps, started, done, last step's sum(ctrl^2)]`.
    fn state(&self) -> Vec<f64> {
        let mut w = StateWriter::default();
        self.sim.save_state(&mut w);
        w.put(&[self.ctrl_sq]);
        w.finish()
    }

    fn set_state(&mut self, state: &[f64]) -> Result<(), EnvError> {
        let mut r = StateReader::new(&self.spec.name, state, self.sim.state_len() + 1)?;
        self.sim.load_state(&mut r, &self.spec.name)?;
        self.ctrl_sq = r.scalar();
        self.sim.data.forward();
        Ok(())
    }
}

/// The task file's path as an absolute path when it exists (so actor processes started
/// elsewhere find it), else as given.
pub fn absolute_task_path(path: &Path) -> PathBuf {
    std::fs::canonicalize(path).unwrap_or_else(|_| path.to_owned())
}

#[cfg(test)]
mod tests;
