//! The run log's 3D scene: a logged evaluation episode as Foxglove draws a robot.
//!
//! | topic | message | when |
//! |---|---|---|
//! | `/scene` | `foxglove.SceneUpdate` | at each logged episode's start: one entity per body, in the body's own frame, each geom a primitive (box, sphere, cylinder; a capsule as a cylinder and two spheres; the floor as a thin box) |
//! | `/tf` | `foxglove.FrameTransforms` | the episode's start and every step: `world` -> each body (MuJoCo's `xpos` / `xquat`) |
//!
//! The schemas are Foxglove's own ([`ess_proto::foxglove`]); the channels carry their
//! descriptor set. An episode's messages are stamped `dt` apart (the env's simulated
//! seconds per step) from its start, so playback shows the motion at real speed; its
//! `/eval/step` records get the same times. Envs without a body model (Traj2D) write
//! no scene.

use ess_actor::EvalEpisode;
use ess_envs::scene::{Body, Pose, Scene, Shape};
use ess_envs::{Env, EnvError};
use ess_proto::foxglove as fx;
use prost_types::{Duration, Timestamp};

/// Topic of the scene entities ([`fx::SceneUpdate`]).
pub const SCENE_TOPIC: &str = "/scene";
/// Topic of the bodies' poses ([`fx::FrameTransforms`]).
pub const TF_TOPIC: &str = "/tf";
/// The scene topics with their schemas, in channel order.
pub const SCENE_TOPICS: [(&str, &str); 2] = [
    (SCENE_TOPIC, "foxglove.SceneUpdate"),
    (TF_TOPIC, "foxglove.FrameTransforms"),
];
/// The frame every body's pose is given in.
pub const WORLD_FRAME: &str = "world";

/// The poses of one episode: the start state's, then one set after each step.
#[derive(Debug, Clone, Default)]
pub struct EpisodePoses(pub Vec<Vec<Pose>>);

/// `ep`'s body poses, replayed on `env` from its recorded states (the start state,
/// then the state after each step).
pub fn episode_poses(env: &mut dyn Env, ep: &EvalEpisode) -> Result<EpisodePoses, EnvError> {
    let sd = ep.state_dim.max(1);
    let steps = ep.states.chunks_exact(sd).take(ep.len());
    poses_of(env, std::iter::once(&ep.start_state[..]).chain(steps)).map_err(|(_, e)| e)
}

/// The body poses of `env` in each of `states`, restored in turn; an error comes with
/// the index of the state the env refused.
pub fn poses_of<'a>(
    env: &mut dyn Env,
    states: impl IntoIterator<Item = &'a [f64]>,
) -> Result<EpisodePoses, (usize, EnvError)> {
    let mut out = Vec::new();
    for (k, state) in states.into_iter().enumerate() {
        env.set_state(state).map_err(|e| (k, e))?;
        out.push(env.body_poses());
    }
    Ok(EpisodePoses(out))
}

pub(crate) fn stamp(ns: u64) -> Timestamp {
    Timestamp {
        seconds: (ns / 1_000_000_000) as i64,
        nanos: (ns % 1_000_000_000) as i32,
    }
}

fn vec3(v: [f64; 3]) -> fx::Vector3 {
    fx::Vector3 {
        x: v[0],
        y: v[1],
        z: v[2],
    }
}

/// A MuJoCo quaternion (w, x, y, z) as Foxglove's.
fn quat(q: [f64; 4]) -> fx::Quaternion {
    fx::Quaternion {
        x: q[1],
        y: q[2],
        z: q[3],
        w: q[0],
    }
}

fn pose(pos: [f64; 3], q: [f64; 4]) -> fx::Pose {
    fx::Pose {
        position: Some(vec3(pos)),
        orientation: Some(quat(q)),
    }
}

/// `q * v` for a unit quaternion (w, x, y, z).
fn rotate(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let [w, x, y, z] = q;
    let t = [
        2.0 * (y * v[2] - z * v[1]),
        2.0 * (z * v[0] - x * v[2]),
        2.0 * (x * v[1] - y * v[0]),
    ];
    [
        v[0] + w * t[0] + (y * t[2] - z * t[1]),
        v[1] + w * t[1] + (z * t[0] - x * t[2]),
        v[2] + w * t[2] + (x * t[1] - y * t[0]),
    ]
}

/// One body as an entity in its own frame.
fn entity(body: &Body, t: Timestamp, episode: u32, code: usize) -> fx::SceneEntity {
    let mut e = fx::SceneEntity {
        timestamp: Some(t),
        frame_id: body.name.clone(),
        id: body.name.clone(),
        lifetime: Some(Duration::default()), // until replaced
        frame_locked: true,
        metadata: vec![
            fx::KeyValuePair {
                key: "episode".into(),
                value: episode.to_string(),
            },
            fx::KeyValuePair {
                key: "code".into(),
                value: code.to_string(),
            },
        ],
        ..Default::default()
    };
    for g in &body.geoms {
        let [r, gr, b, a] = g.rgba.map(f64::from);
        let color = Some(fx::Color { r, g: gr, b, a });
        let cylinder = |radius: f64, half: f64| fx::CylinderPrimitive {
            pose: Some(pose(g.pos, g.quat)),
            size: Some(vec3([2.0 * radius, 2.0 * radius, 2.0 * half])),
            bottom_scale: 1.0,
            top_scale: 1.0,
            color,
        };
        let sphere = |centre: [f64; 3], d: [f64; 3]| fx::SpherePrimitive {
            pose: Some(pose(centre, g.quat)),
            size: Some(vec3(d)),
            color,
        };
        let cube = |half: [f64; 3]| fx::CubePrimitive {
            pose: Some(pose(g.pos, g.quat)),
            size: Some(vec3(half.map(|h| 2.0 * h))),
            color,
        };
        match g.shape {
            Shape::Box(h) => e.cubes.push(cube(h)),
            // An unbounded plane drawn 20 m wide, 1 cm thick.
            Shape::Plane([x, y]) => e.cubes.push(cube([
                if x > 0.0 { x } else { 10.0 },
                if y > 0.0 { y } else { 10.0 },
                0.005,
            ])),
            Shape::Sphere(r) => e.spheres.push(sphere(g.pos, [2.0 * r; 3])),
            Shape::Ellipsoid(r) => e.spheres.push(sphere(g.pos, r.map(|x| 2.0 * x))),
            Shape::Cylinder(r, h) => e.cylinders.push(cylinder(r, h)),
            Shape::Capsule(r, h) => {
                e.cylinders.push(cylinder(r, h));
                for s in [-1.0, 1.0] {
                    let off = rotate(g.quat, [0.0, 0.0, s * h]);
                    let c = [g.pos[0] + off[0], g.pos[1] + off[1], g.pos[2] + off[2]];
                    e.spheres.push(sphere(c, [2.0 * r; 3]));
                }
            }
        }
    }
    e
}

/// The `/scene` message of an episode's start: every body with geoms.
pub fn scene_update(scene: &Scene, t_ns: u64, episode: u32, code: usize) -> fx::SceneUpdate {
    let t = stamp(t_ns);
    fx::SceneUpdate {
        deletions: Vec::new(),
        entities: scene
            .bodies
            .iter()
            .filter(|b| !b.geoms.is_empty())
            .map(|b| entity(b, t, episode, code))
            .collect(),
    }
}

/// The `/tf` message of one step: `world` -> each body (the world body excluded).
pub fn transforms(scene: &Scene, poses: &[Pose], t_ns: u64) -> fx::FrameTransforms {
    let t = stamp(t_ns);
    fx::FrameTransforms {
        transforms: scene
            .bodies
            .iter()
            .zip(poses)
            .filter(|(b, _)| b.name != WORLD_FRAME)
            .map(|(b, p)| fx::FrameTransform {
                timestamp: Some(t),
                parent_frame_id: WORLD_FRAME.into(),
                child_frame_id: b.name.clone(),
                translation: Some(vec3(p.pos)),
                rotation: Some(quat(p.quat)),
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotating_by_a_quarter_turn_about_x_takes_z_to_minus_y() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let v = rotate([h, h, 0.0, 0.0], [0.0, 0.0, 1.0]);
        assert!(v[0].abs() < 1e-12 && (v[1] + 1.0).abs() < 1e-12 && v[2].abs() < 1e-12);
    }

    #[test]
    fn a_humanoid_scene_has_an_entity_per_body_with_geoms_and_a_transform_per_body() {
        let mut env = ess_envs::Humanoid::new(Default::default()).expect("humanoid");
        let mut obs = vec![0.0; env.spec().obs_dim];
        env.reset(0, &mut obs).expect("reset");
        let scene = env.scene().expect("scene");
        let up = scene_update(&scene, 1_500_000_000, 7, 2);
        let with_geoms = scene.bodies.iter().filter(|b| !b.geoms.is_empty()).count();
        assert_eq!(up.entities.len(), with_geoms);
        let torso = up.entities.iter().find(|e| e.id == "torso").expect("torso");
        assert_eq!(torso.frame_id, "torso");
        assert!(!torso.cylinders.is_empty() && torso.spheres.len() >= 2);
        let tf = transforms(&scene, &env.body_poses(), 1_500_000_000);
        assert_eq!(tf.transforms.len(), scene.bodies.len() - 1);
        assert!(
            tf.transforms
                .iter()
                .all(|t| t.parent_frame_id == WORLD_FRAME)
        );
        assert_eq!(tf.transforms[0].timestamp, Some(stamp(1_500_000_000)));
    }
}
