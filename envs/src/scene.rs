//! What a 3D viewer needs to draw an env: its bodies, each geom as a primitive in its
//! body's frame ([`Scene`]), and the bodies' world poses after a step ([`Pose`]). The
//! run log turns them into Foxglove's `SceneUpdate` and `FrameTransforms` messages so a
//! logged episode plays back as a moving robot. Every MuJoCo env reads both from its
//! model and data (`crate::mujoco::scene` and `crate::mujoco::poses`): MuJoCo's
//! `geom_*` and `xpos` / `xquat`. This file holds the types alone, so the `Env` trait
//! can name them without depending on MuJoCo.

/// A geom's shape; sizes in metres as MuJoCo gives them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// An axis-aligned box with these half extents.
    Box([f64; 3]),
    /// A sphere of this radius.
    Sphere(f64),
    /// A capsule along z: radius, half length of the cylinder part.
    Capsule(f64, f64),
    /// A cylinder along z: radius, half length.
    Cylinder(f64, f64),
    /// An ellipsoid with these radii.
    Ellipsoid([f64; 3]),
    /// A plane (the floor): half extents in x and y (0: unbounded).
    Plane([f64; 2]),
}

/// One geom, in its body's frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Geom {
    /// Its shape.
    pub shape: Shape,
    /// Position in the body frame.
    pub pos: [f64; 3],
    /// Orientation in the body frame, quaternion (w, x, y, z).
    pub quat: [f64; 4],
    /// Colour (red, green, blue, alpha in 0..1).
    pub rgba: [f32; 4],
}

/// A body: its name (the frame its geoms are drawn in) and geoms.
#[derive(Debug, Clone, PartialEq)]
pub struct Body {
    /// MuJoCo's body name (`body<i>` for an unnamed one).
    pub name: String,
    /// Its geoms (mesh and height-field geoms are left out).
    pub geoms: Vec<Geom>,
}

/// The drawable model of an env.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Bodies in MuJoCo's order, the world body first; [`Pose`]s come in this order.
    pub bodies: Vec<Body>,
    /// Simulated seconds per env step, for playback at real speed.
    pub dt: f64,
}

/// A body's world pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position (`xpos`).
    pub pos: [f64; 3],
    /// Orientation (`xquat`: w, x, y, z).
    pub quat: [f64; 4],
}

#[cfg(test)]
mod tests {
    use crate::{Env, Humanoid, HumanoidConfig, Reacher, ReacherConfig, Traj2D, Traj2DConfig};

    #[test]
    fn humanoid_draws_its_bodies_and_they_move_when_it_steps() {
        let mut env = Humanoid::new(HumanoidConfig::default()).expect("humanoid");
        let mut obs = vec![0.0; env.spec().obs_dim];
        env.reset(3, &mut obs).expect("reset");
        let scene = env.scene().expect("a MuJoCo env has a scene");
        assert_eq!(scene.bodies[0].name, "world");
        assert!(scene.bodies.iter().any(|b| b.name == "torso"));
        // The floor on the world body, capsules for the limbs.
        assert!(
            scene.bodies[0]
                .geoms
                .iter()
                .any(|g| matches!(g.shape, super::Shape::Plane(_)))
        );
        let capsules = scene.bodies.iter().flat_map(|b| &b.geoms);
        assert!(
            capsules
                .filter(|g| matches!(g.shape, super::Shape::Capsule(..)))
                .count()
                >= 10
        );
        assert!((scene.dt - 0.015).abs() < 1e-12, "{}", scene.dt);
        let before = env.body_poses();
        assert_eq!(before.len(), scene.bodies.len());
        let act = vec![0.4; env.spec().act_dim];
        for _ in 0..5 {
            env.step(&act, &mut obs).expect("step");
        }
        let after = env.body_poses();
        let torso = scene
            .bodies
            .iter()
            .position(|b| b.name == "torso")
            .expect("torso");
        assert_ne!(before[torso], after[torso]);
        for p in &after {
            let n: f64 = p.quat.iter().map(|q| q * q).sum();
            assert!((n - 1.0).abs() < 1e-9, "unit quaternion: {p:?}");
        }
    }

    #[test]
    fn reacher_has_a_scene_and_traj2d_has_none() {
        let env = Reacher::new(ReacherConfig::default()).expect("reacher");
        let scene = env.scene().expect("scene");
        assert_eq!(scene.bodies.iter().map(|b| b.geoms.len()).sum::<usize>(), 3); // floor, two links
        let t = Traj2D::new(Traj2DConfig::default()).expect("traj2d");
        assert!(t.scene().is_none() && t.body_poses().is_empty());
    }
}
