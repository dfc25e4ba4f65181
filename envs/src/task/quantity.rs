//! Named pieces of a MuJoCo state, resolved once against the model: observation
//! pieces (vectors) and scalar quantities (termination, rewards). Reading them never
//! allocates.

use mujoco_rs::prelude::{MjModel, MjtJoint, MjtObjBase};

use crate::mujoco::Data;

/// Where a piece's values come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Source {
    /// `qpos[start..start + len]`.
    Qpos,
    /// `qvel[start..start + len]`.
    Qvel,
    /// `sensordata[start..start + len]`.
    Sensor,
    /// Body `id`'s `xpos` (3).
    BodyPos(usize),
    /// Body `id`'s world velocity, angular then linear (6).
    BodyVel(usize),
    /// Body `id`'s `xquat` (4).
    BodyQuat(usize),
}

/// A resolved vector: `len` values of `source` from `start`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Span {
    pub source: Source,
    pub start: usize,
    pub len: usize,
}

impl Span {
    /// The span's value at `i` (< `len`) in `data`'s current state.
    pub fn get(&self, data: &Data, i: usize) -> f64 {
        let at = self.start + i;
        match self.source {
            Source::Qpos => data.qpos()[at],
            Source::Qvel => data.qvel()[at],
            Source::Sensor => data.sensordata()[at],
            Source::BodyPos(b) => data.xpos()[b][i],
            Source::BodyQuat(b) => data.xquat()[b][i],
            Source::BodyVel(b) => data.object_velocity(MjtObjBase::mjOBJ_BODY, b, false)[i],
        }
    }

    /// Writes the whole span into `out` (len `self.len`).
    pub fn write(&self, data: &Data, out: &mut [f64]) {
        let mut slice = |v: &[f64]| out.copy_from_slice(&v[self.start..self.start + self.len]);
        match self.source {
            Source::Qpos => slice(data.qpos()),
            Source::Qvel => slice(data.qvel()),
            Source::Sensor => slice(data.sensordata()),
            Source::BodyPos(b) => out.copy_from_slice(&data.xpos()[b]),
            Source::BodyQuat(b) => out.copy_from_slice(&data.xquat()[b]),
            Source::BodyVel(b) => {
                out.copy_from_slice(&data.object_velocity(MjtObjBase::mjOBJ_BODY, b, false))
            }
        }
    }
}

fn id(model: &MjModel, kind: MjtObjBase, what: &str, name: &str) -> Result<usize, String> {
    model
        .name_to_id(kind, name)
        .ok_or_else(|| format!("the model has no {what} named {name:?}"))
}

/// The id of the body named `name`.
pub(crate) fn body_id(model: &MjModel, name: &str) -> Result<usize, String> {
    id(model, MjtObjBase::mjOBJ_BODY, "body", name)
}

fn to_usize(x: i32) -> usize {
    usize::try_from(x).unwrap_or(0)
}

/// The span of `key` (`qpos`, `qvel`, `sensor`, `body_pos`, `body_vel`, `body_quat`)
/// named `name` (`"*"`: the whole vector, for `qpos`, `qvel` and `sensor`).
pub(crate) fn resolve_span(model: &MjModel, key: &str, name: &str) -> Result<Span, String> {
    let f = model.ffi();
    let whole = |source, len: i64| Span {
        source,
        start: 0,
        len: usize::try_from(len).unwrap_or(0),
    };
    let body = |source: fn(usize) -> Source, len| {
        body_id(model, name).map(|b| Span {
            source: source(b),
            start: 0,
            len,
        })
    };
    Ok(match (key, name) {
        ("qpos", "*") => whole(Source::Qpos, f.nq),
        ("qvel", "*") => whole(Source::Qvel, f.nv),
        ("sensor", "*") => whole(Source::Sensor, f.nsensordata),
        ("qpos" | "qvel", _) => {
            let j = id(model, MjtObjBase::mjOBJ_JOINT, "joint", name)?;
            let (nq, nv) = match model.jnt_type()[j] {
                MjtJoint::mjJNT_FREE => (7, 6),
                MjtJoint::mjJNT_BALL => (4, 3),
                _ => (1, 1),
            };
            if key == "qpos" {
                Span {
                    source: Source::Qpos,
                    start: to_usize(model.jnt_qposadr()[j]),
                    len: nq,
                }
            } else {
                Span {
                    source: Source::Qvel,
                    start: to_usize(model.jnt_dofadr()[j]),
                    len: nv,
                }
            }
        }
        ("sensor", _) => {
            let s = id(model, MjtObjBase::mjOBJ_SENSOR, "sensor", name)?;
            Span {
                source: Source::Sensor,
                start: to_usize(model.sensor_adr()[s]),
                len: to_usize(model.sensor_dim()[s]),
            }
        }
        ("body_pos", _) => body(Source::BodyPos, 3)?,
        ("body_vel", _) => body(Source::BodyVel, 6)?,
        ("body_quat", _) => body(Source::BodyQuat, 4)?,
        _ => {
            return Err(format!(
                "unknown source {key:?}; known: qpos, qvel, sensor, body_pos, body_vel, body_quat"
            ));
        }
    })
}

/// A named scalar: one entry of a span, or the step's squared control.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Scalar {
    /// Entry `index` of the span.
    Entry(Span, usize),
    /// `sum(ctrl^2)` of the last step (0 before the first).
    CtrlSq,
}

impl Scalar {
    /// The value in `data`'s state, with `ctrl_sq` the last step's squared control.
    pub fn get(&self, data: &Data, ctrl_sq: f64) -> f64 {
        match self {
            Scalar::Entry(span, i) => span.get(data, *i),
            Scalar::CtrlSq => ctrl_sq,
        }
    }
}

/// Parses a scalar quantity: `ctrl_sq`, `qpos.JOINT[.i]`, `qvel.JOINT[.i]`,
/// `sensor.NAME[.i]`, `body_pos.BODY.x|y|z`, `body_vel.BODY.x|y|z|wx|wy|wz` (linear,
/// then angular world velocity), `body_quat.BODY.w|x|y|z`.
pub(crate) fn resolve_scalar(model: &MjModel, text: &str) -> Result<Scalar, String> {
    if text == "ctrl_sq" {
        return Ok(Scalar::CtrlSq);
    }
    let Some((key, rest)) = text.split_once('.') else {
        return Err(format!(
            "quantity {text:?}: expected ctrl_sq or SOURCE.NAME[.INDEX] (e.g. \
             body_pos.torso.z, qpos.hinge)"
        ));
    };
    let (name, suffix) = match rest.rsplit_once('.') {
        Some((n, s)) if entry_index(key, s).is_some() => (n, Some(s)),
        _ => (rest, None),
    };
    let span = resolve_span(model, key, name).map_err(|e| format!("quantity {text:?}: {e}"))?;
    let index = match suffix {
        Some(s) => entry_index(key, s).unwrap_or(0),
        None if span.len == 1 => 0,
        None => {
            return Err(format!(
                "quantity {text:?}: {key} of {name:?} has {} entries; name one (e.g. \
                 {key}.{name}.{})",
                span.len,
                entry_example(key)
            ));
        }
    };
    if index >= span.len {
        return Err(format!(
            "quantity {text:?}: index {index} is out of range ({key} of {name:?} has {} entries)",
            span.len
        ));
    }
    Ok(Scalar::Entry(span, index))
}

/// The entry index a suffix names for `key`: axis letters for bodies, numbers otherwise.
fn entry_index(key: &str, suffix: &str) -> Option<usize> {
    match (key, suffix) {
        ("body_pos", "x") | ("body_quat", "w") => Some(0),
        ("body_pos", "y") | ("body_quat", "x") => Some(1),
        ("body_pos", "z") | ("body_quat", "y") => Some(2),
        ("body_quat", "z") => Some(3),
        ("body_vel", "wx") => Some(0),
        ("body_vel", "wy") => Some(1),
        ("body_vel", "wz") => Some(2),
        ("body_vel", "x") => Some(3),
        ("body_vel", "y") => Some(4),
        ("body_vel", "z") => Some(5),
        ("qpos" | "qvel" | "sensor", s) => s.parse().ok(),
        _ => None,
    }
}

fn entry_example(key: &str) -> &'static str {
    match key {
        "body_pos" | "body_vel" => "x",
        "body_quat" => "w",
        _ => "0",
    }
}

/// The indices of a piece of `len` entries kept by `take` or `drop`.
pub(crate) fn kept(
    len: usize,
    take: Option<&[usize]>,
    drop: Option<&[usize]>,
) -> Result<Vec<usize>, String> {
    if let Some(&i) = take.into_iter().chain(drop).flatten().find(|&&i| i >= len) {
        return Err(format!(
            "index {i} is out of range: the piece has {len} entries"
        ));
    }
    let keep: Vec<usize> = match (take, drop) {
        (Some(t), _) => t.to_vec(),
        (None, Some(d)) => (0..len).filter(|i| !d.contains(i)).collect(),
        (None, None) => (0..len).collect(),
    };
    if keep.is_empty() {
        return Err("keeps no entry".into());
    }
    Ok(keep)
}
