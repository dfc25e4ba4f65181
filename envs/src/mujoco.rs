//! What every MuJoCo env ([`crate::reacher`], [`crate::pusher`] and the locomotion envs
//! through [`crate::locomotion`]) does the same way: loading an MJCF model, and MuJoCo
//! warnings, which end the episode as [`EnvError::Simulation`].

use mujoco_rs::prelude::{MjData, MjModel};

use crate::env::{EnvError, StateReader, StateWriter};
use crate::scene::{Body, Geom, Pose, Scene, Shape};
use mujoco_rs::prelude::{MjtGeomBase, MjtObjBase};

/// The MuJoCo state an env owns, with its model.
pub(crate) type Data = MjData<Box<MjModel>>;

/// The part of MuJoCo's state that [`crate::Env::state`] saves: everything
/// `mj_step` reads (`mjSTATE_INTEGRATION`: time, qpos, qvel, act, warm start, controls,
/// applied forces, mocap, ...), so a restored env steps bit-identically.
const STATE_SPEC: u32 = mujoco_rs::prelude::MjtState::mjSTATE_INTEGRATION as u32;

/// Length of [`physics_state`]'s output for `data`'s model.
pub(crate) fn physics_state_len(data: &Data) -> usize {
    data.model().state_size(STATE_SPEC)
}

/// Appends `data`'s integration state to `out`.
pub(crate) fn physics_state(data: &Data, out: &mut Vec<f64>) {
    out.extend_from_slice(&data.state(STATE_SPEC));
}

/// Restores an integration state from [`physics_state`] (length already checked by the
/// caller) and recomputes positions (`mj_kinematics`), as the envs' `step` leaves them.
pub(crate) fn set_physics_state(data: &mut Data, state: &[f64], env: &str) -> Result<(), EnvError> {
    data.set_state(state, STATE_SPEC)
        .map_err(|e| EnvError::BadState {
            env: env.to_owned(),
            why: e.to_string(),
        })?;
    data.forward_kinematics();
    Ok(())
}

/// [`crate::Env::state`] of an arm env (Reacher, Pusher): `[integration state, last
/// action, steps, started, done]`.
pub(crate) fn arm_state(
    data: &Data,
    last_action: &[f64],
    steps: usize,
    started: bool,
    done: bool,
) -> Vec<f64> {
    let mut physics = Vec::new();
    physics_state(data, &mut physics);
    StateWriter::default()
        .put(&physics)
        .put(last_action)
        .count(steps)
        .flag(started)
        .flag(done)
        .finish()
}

/// Restores an [`arm_state`] vector: the physics into `data`, the action into
/// `last_action`; returns `(steps, started, done)`. Nothing changes when the vector is
/// refused for its length or values.
pub(crate) fn set_arm_state(
    data: &mut Data,
    env: &str,
    state: &[f64],
    last_action: &mut [f64],
    max_steps: usize,
) -> Result<(usize, bool, bool), EnvError> {
    let n = physics_state_len(data);
    let mut r = StateReader::new(env, state, n + last_action.len() + 3)?;
    let physics = r.take(n);
    let action = r.take(last_action.len());
    let steps = r.count("steps", max_steps)?;
    let started = r.flag("started")?;
    let done = r.flag("done")?;
    set_physics_state(data, physics, env)?;
    last_action.copy_from_slice(action);
    Ok((steps, started, done))
}

/// [`EnvError::Model`] with `reason`.
pub(crate) fn model_error(reason: impl Into<String>) -> EnvError {
    EnvError::Model {
        reason: reason.into(),
    }
}

/// Parses the MJCF model `xml`; MuJoCo's message is the [`EnvError::Model`] reason.
pub(crate) fn load_model(xml: &str) -> Result<MjModel, EnvError> {
    MjModel::from_xml_string(xml).map_err(|e| model_error(e.to_string()))
}

/// Allocates the state of `model`.
pub(crate) fn new_data(model: MjModel) -> Result<Data, EnvError> {
    MjData::try_new(Box::new(model)).map_err(|e| model_error(e.to_string()))
}

/// MuJoCo warning counters, by warning type, since the last reset.
pub(crate) fn warning_counts(data: &Data) -> Vec<i32> {
    data.warning().iter().map(|w| w.number).collect()
}

/// Errors when MuJoCo raised any warning since the last reset; `steps` (env steps of
/// the episode) goes into the message.
pub(crate) fn check_warnings(data: &Data, steps: usize) -> Result<(), EnvError> {
    match data.warning().iter().position(|w| w.number > 0) {
        Some(index) => Err(EnvError::Simulation {
            reason: format!(
                "MuJoCo warning type {index} raised {} time(s) by step {steps} (info {}); \
                 the model is unstable or misconfigured",
                data.warning()[index].number,
                data.warning()[index].lastinfo
            ),
        }),
        None => Ok(()),
    }
}

/// A MuJoCo geom's shape, `None` for the kinds a primitive cannot draw (meshes,
/// height fields, signed-distance fields).
fn shape(kind: MjtGeomBase, size: [f64; 3]) -> Option<Shape> {
    Some(match kind {
        MjtGeomBase::mjGEOM_PLANE => Shape::Plane([size[0], size[1]]),
        MjtGeomBase::mjGEOM_SPHERE => Shape::Sphere(size[0]),
        MjtGeomBase::mjGEOM_CAPSULE => Shape::Capsule(size[0], size[1]),
        MjtGeomBase::mjGEOM_ELLIPSOID => Shape::Ellipsoid(size),
        MjtGeomBase::mjGEOM_CYLINDER => Shape::Cylinder(size[0], size[1]),
        MjtGeomBase::mjGEOM_BOX => Shape::Box(size),
        _ => return None,
    })
}

/// The bodies and geoms of `data`'s model; `dt` seconds per env step.
pub(crate) fn scene(data: &Data, dt: f64) -> Scene {
    let m = data.model();
    let nbody = m.ffi().nbody.max(0) as usize;
    let mut bodies: Vec<Body> = (0..nbody)
        .map(|b| Body {
            name: match m.id_to_name(MjtObjBase::mjOBJ_BODY, b) {
                Some(n) if !n.is_empty() => n.to_string(),
                _ => format!("body{b}"),
            },
            geoms: Vec::new(),
        })
        .collect();
    let (kinds, sizes, rgba) = (m.geom_type(), m.geom_size(), m.geom_rgba());
    let (pos, quat, owner) = (m.geom_pos(), m.geom_quat(), m.geom_bodyid());
    for g in 0..kinds.len() {
        let Some(shape) = shape(kinds[g], sizes[g]) else {
            continue;
        };
        if let Some(body) = usize::try_from(owner[g])
            .ok()
            .and_then(|b| bodies.get_mut(b))
        {
            body.geoms.push(Geom {
                shape,
                pos: pos[g],
                quat: quat[g],
                rgba: rgba[g],
            });
        }
    }
    Scene { bodies, dt }
}

/// The world pose of each body of `data` now, in [`Scene::bodies`]' order.
pub(crate) fn poses(data: &Data) -> Vec<Pose> {
    data.xpos()
        .iter()
        .zip(data.xquat())
        .map(|(p, q)| Pose { pos: *p, quat: *q })
        .collect()
}
