//! The task file: what a user writes (TOML), parsed and checked before any model is
//! loaded. The format is documented in [`crate::task`].

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::env::EnvError;

/// A task file as written.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaskFile {
    /// Short name for messages and run directories; default: the file's stem.
    #[serde(default)]
    pub name: Option<String>,
    /// The MJCF model, relative to the task file.
    pub mjcf: PathBuf,
    /// Physics steps per env step.
    #[serde(default = "one")]
    pub frame_skip: usize,
    /// Episode length in env steps; the step reaching it is `truncated`.
    pub max_steps: usize,
    /// Half-width of the uniform noise added to every `qpos` (around the model's
    /// `qpos0`) and `qvel` (around 0) entry at reset.
    #[serde(default)]
    pub reset_noise: f64,
    /// The observation, piece after piece.
    pub obs: Vec<ObsPiece>,
    /// Conditions that end an episode `terminated`.
    #[serde(default)]
    pub terminate: Vec<Terminate>,
    /// Per-mode evaluation rewards (optional; their count must match the modes).
    #[serde(default)]
    pub modes: Vec<ModeReward>,
}

fn one() -> usize {
    1
}

/// One piece of the observation: exactly one source key, optionally sliced.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObsPiece {
    /// `qpos` of a named joint, or `"*"` for all of `qpos`.
    pub qpos: Option<String>,
    /// `qvel` of a named joint, or `"*"` for all of `qvel`.
    pub qvel: Option<String>,
    /// A named sensor's values, or `"*"` for all of `sensordata`.
    pub sensor: Option<String>,
    /// A named body's world position (`xpos`, 3).
    pub body_pos: Option<String>,
    /// A named body's world velocity (angular then linear, 6).
    pub body_vel: Option<String>,
    /// A named body's world orientation quaternion (`xquat`, 4).
    pub body_quat: Option<String>,
    /// Keep only these entries of the piece (0-based).
    pub take: Option<Vec<usize>>,
    /// Keep every entry of the piece but these.
    pub drop: Option<Vec<usize>>,
    /// Clip every entry to `[-clip, clip]`.
    pub clip: Option<f64>,
}

/// An episode ends `terminated` when `quantity` leaves `range` (`lo < x < hi` holds
/// while it goes on).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Terminate {
    /// A named scalar quantity (see [`crate::task`]).
    pub quantity: String,
    /// The open range the quantity must stay in.
    pub range: [f64; 2],
}

/// One behaviour mode's evaluation reward: a weighted sum of terms.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModeReward {
    /// The mode's name (for reports).
    pub name: String,
    /// The terms, summed.
    pub reward: Vec<RewardTerm>,
}

/// `weight * quantity`, or `weight * distance(body, to)`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RewardTerm {
    /// A named scalar quantity.
    pub quantity: Option<String>,
    /// A body whose Euclidean distance to `to` or `to_body` is the term.
    pub distance: Option<String>,
    /// A fixed world point.
    pub to: Option<[f64; 3]>,
    /// Another body.
    pub to_body: Option<String>,
    /// The term's weight.
    pub weight: f64,
}

/// [`EnvError::Task`] for `path`.
pub(crate) fn task_error(path: &Path, reason: impl Into<String>) -> EnvError {
    EnvError::Task {
        path: path.to_owned(),
        reason: reason.into(),
    }
}

/// The most bytes a task file may have; real ones are a few KB.
pub const MAX_TASK_FILE_BYTES: u64 = 1 << 20;

/// Reads a task file's text: a regular file of at most [`MAX_TASK_FILE_BYTES`]. A job
/// spec names its task file by path on the server, so a FIFO, a device (`/dev/zero`,
/// `/dev/stdin`) or a huge file must be refused, not read until memory runs out.
fn read_capped(path: &Path) -> std::io::Result<String> {
    use std::io::Read;
    let file = crate::read::open_regular(path)?;
    let mut text = String::new();
    file.take(MAX_TASK_FILE_BYTES + 1)
        .read_to_string(&mut text)?;
    if text.len() as u64 > MAX_TASK_FILE_BYTES {
        return Err(std::io::Error::other(format!(
            "larger than {MAX_TASK_FILE_BYTES} bytes; a task file is a short TOML file"
        )));
    }
    Ok(text)
}

impl TaskFile {
    /// Reads and checks `path`; errors name the file, the line where TOML could say it,
    /// and the key.
    pub fn read(path: &Path) -> Result<Self, EnvError> {
        let text = read_capped(path).map_err(|e| task_error(path, format!("cannot read: {e}")))?;
        Self::parse(path, &text)
    }

    /// Parses and checks the text of a task file; `path` names it in errors.
    pub fn parse(path: &Path, text: &str) -> Result<Self, EnvError> {
        let file: TaskFile = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| {
                    let n = text[..s.start].matches('\n').count();
                    let src = text.lines().nth(n).unwrap_or("").trim();
                    format!("line {} (`{src}`): ", n + 1)
                })
                .unwrap_or_default();
            task_error(path, format!("{line}{}", e.message().trim()))
        })?;
        file.check(path)?;
        Ok(file)
    }

    /// Checks what can be checked without the model.
    fn check(&self, path: &Path) -> Result<(), EnvError> {
        let bad = |what: String| Err(task_error(path, what));
        if self.frame_skip == 0 {
            return bad("frame_skip = 0: must be at least 1".into());
        }
        if self.max_steps == 0 {
            return bad("max_steps = 0: must be at least 1".into());
        }
        if !(self.reset_noise.is_finite() && self.reset_noise >= 0.0) {
            return bad(format!(
                "reset_noise = {}: must be finite and >= 0",
                self.reset_noise
            ));
        }
        if self.obs.is_empty() {
            return bad("obs: the observation needs at least one piece".into());
        }
        for (i, p) in self.obs.iter().enumerate() {
            p.check()
                .map_err(|why| task_error(path, format!("obs[{i}]: {why}")))?;
        }
        for (i, t) in self.terminate.iter().enumerate() {
            let [lo, hi] = t.range;
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return bad(format!(
                    "terminate[{i}].range = [{lo}, {hi}]: must be finite with lo < hi"
                ));
            }
        }
        for (i, m) in self.modes.iter().enumerate() {
            if m.reward.is_empty() {
                return bad(format!(
                    "modes[{i}] ({:?}).reward: needs at least one term",
                    m.name
                ));
            }
            for (j, t) in m.reward.iter().enumerate() {
                t.check()
                    .map_err(|why| task_error(path, format!("modes[{i}].reward[{j}]: {why}")))?;
            }
        }
        Ok(())
    }

    /// The MJCF path, resolved against the task file's directory.
    pub fn mjcf_path(&self, task_path: &Path) -> PathBuf {
        task_path
            .parent()
            .unwrap_or_else(|| Path::new("."))
            .join(&self.mjcf)
    }
}

impl ObsPiece {
    /// The one source key set, as `(key, name)`.
    pub fn source(&self) -> Result<(&'static str, &str), String> {
        let keys = [
            ("qpos", &self.qpos),
            ("qvel", &self.qvel),
            ("sensor", &self.sensor),
            ("body_pos", &self.body_pos),
            ("body_vel", &self.body_vel),
            ("body_quat", &self.body_quat),
        ];
        let set: Vec<_> = keys
            .iter()
            .filter_map(|(k, v)| v.as_deref().map(|v| (*k, v)))
            .collect();
        match set.as_slice() {
            [one] => Ok(*one),
            [] => Err(
                "names no source: give one of qpos, qvel, sensor, body_pos, body_vel, \
                       body_quat"
                    .into(),
            ),
            _ => Err(format!(
                "names {} sources ({}); give exactly one per piece",
                set.len(),
                set.iter().map(|(k, _)| *k).collect::<Vec<_>>().join(", ")
            )),
        }
    }

    fn check(&self) -> Result<(), String> {
        self.source()?;
        if self.take.is_some() && self.drop.is_some() {
            return Err("has both take and drop; give at most one".into());
        }
        if let Some(c) = self.clip
            && !(c.is_finite() && c > 0.0)
        {
            return Err(format!("clip = {c}: must be finite and > 0"));
        }
        Ok(())
    }
}

impl RewardTerm {
    fn check(&self) -> Result<(), String> {
        if !self.weight.is_finite() {
            return Err(format!("weight = {}: must be finite", self.weight));
        }
        match (&self.quantity, &self.distance) {
            (Some(_), None) if self.to.is_none() && self.to_body.is_none() => Ok(()),
            (Some(_), None) => Err("to / to_body belong to a distance term".into()),
            (None, Some(_)) => match (&self.to, &self.to_body) {
                (Some(p), None) if p.iter().all(|x| x.is_finite()) => Ok(()),
                (Some(p), None) => Err(format!("to = {p:?}: must be finite")),
                (None, Some(_)) => Ok(()),
                _ => Err("a distance term needs exactly one of to, to_body".into()),
            },
            _ => Err("needs exactly one of quantity, distance".into()),
        }
    }
}
