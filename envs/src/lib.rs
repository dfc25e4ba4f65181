//! `ess-envs`: environments, scripted experts, per-mode evaluation rewards and
//! demonstration datasets for Ess.
//!
//! - [`env`](mod@env): the [`Env`] contract every environment obeys, the [`ScriptedExpert`]
//!   extension for environments with scripted multi-modal experts, [`make_env`] (envs
//!   with a scripted expert) and [`make_plain_env`] (every env).
//! - [`traj2d`]: the 2D trajectory task of the paper (Sec. 4, Fig. 1): four circular
//!   behaviour modes through the origin.
//! - [`reacher`]: the multi-target Reacher task (Sec. 4, "Task setup (2)") on MuJoCo:
//!   a two-link arm, one hidden target per behaviour mode.
//! - [`locomotion`]: what the locomotion envs share: the three modes (run forward, run
//!   backward, balance), their per-mode reward and the MuJoCo simulation core.
//! - [`walker2d`]: Walker-2D (Sec. 4, "Task setup (4)") on MuJoCo, Gymnasium
//!   Walker2d-v5's model and spaces with three behaviour modes; no scripted expert
//!   (its experts are PPO-trained).
//! - [`humanoid`]: Humanoid (Sec. 4, "Task setup (5)") on MuJoCo, Gymnasium
//!   Humanoid-v5's model and spaces with the same three modes; no scripted expert.
//! - [`demos`]: imbalanced, partly labeled demonstration datasets (paper Sec. 4,
//!   "Multi-modal demonstrations preparation") and their safetensors file format.
//!
//! This crate never links libtorch, tokio or tonic; it links MuJoCo (through
//! `mujoco-rs`) for [`reacher`] and the locomotion envs.

pub mod demos;
pub mod env;
pub mod humanoid;
pub mod locomotion;
pub mod reacher;
pub mod traj2d;
pub mod walker2d;

pub use demos::{
    DemoError, DemoMeta, DemoSpec, DemoSplit, Demos, expert_episode, generate_demos, mode_weights,
};
pub use env::{Env, EnvError, EnvSpec, ScriptedExpert, StepOutcome, make_env, make_plain_env};
pub use humanoid::{Humanoid, HumanoidConfig};
pub use locomotion::LocoMode;
pub use reacher::{Reacher, ReacherConfig};
pub use traj2d::{Traj2D, Traj2DConfig};
pub use walker2d::{Walker2d, Walker2dConfig};
