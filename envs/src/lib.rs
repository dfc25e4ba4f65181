//! `ess-envs`: environments, scripted experts, per-mode evaluation rewards and
//! demonstration datasets for Ess.
//!
//! - [`env`](mod@env): the [`Env`] contract every environment obeys and the
//!   [`ScriptedExpert`] extension for environments with scripted multi-modal experts.
//! - [`registry`]: one line per env (its file's `ENTRY`): [`make_env`] (envs with their
//!   experts), [`make_plain_env`] (every env), and how to add a task.
//! - [`traj2d`]: the 2D trajectory task of the paper (Sec. 4, Fig. 1): four circular
//!   behaviour modes through the origin.
//! - [`reacher`]: the multi-target Reacher task (Sec. 4, "Task setup (2)") on MuJoCo:
//!   a two-link arm, one hidden target per behaviour mode.
//! - [`expert`]: trained expert policies (one per mode), their file format, and
//!   [`ExpertEnv`], which drives any env with them for demonstrations.
//! - [`pusher`]: the multi-goal Pusher task (Sec. 4, "Task setup (3)") on MuJoCo: a
//!   7-DoF arm pushes a puck, one hidden goal per behaviour mode; no scripted expert.
//! - [`locomotion`]: what the locomotion envs share: the three modes (run forward, run
//!   backward, balance), their per-mode reward and the MuJoCo simulation core.
//! - [`walker2d`]: Walker-2D (Sec. 4, "Task setup (4)") on MuJoCo, Gymnasium
//!   Walker2d-v5's model and spaces with three behaviour modes; no scripted expert
//!   (its experts are PPO-trained).
//! - [`humanoid`]: Humanoid (Sec. 4, "Task setup (5)") on MuJoCo, Gymnasium
//!   Humanoid-v5's model and spaces with the same three modes; no scripted expert.
//! - [`task`]: a task from the user's own MJCF model, described by a TOML task file
//!   (observation pieces, actions, episode, optional per-mode rewards).
//! - [`read`]: reading a file named by outside input: regular files only, never blocking.
//! - [`demos`]: imbalanced, partly labeled demonstration datasets (paper Sec. 4,
//!   "Multi-modal demonstrations preparation") and their safetensors file format.
//!
//! This crate never links libtorch, tokio or tonic; it links MuJoCo (through
//! `mujoco-rs`) for [`reacher`], [`pusher`] and the locomotion envs.

mod atomic;
pub mod demos;
pub mod env;
pub mod expert;
pub mod humanoid;
pub mod locomotion;
mod mujoco;
pub mod pusher;
pub mod reacher;
pub mod read;
pub mod registry;
pub mod scene;
pub mod task;
pub mod traj2d;
pub mod walker2d;

pub use demos::{
    DemoError, DemoMeta, DemoSpec, DemoSplit, Demos, expert_episode, generate_demos, mode_weights,
};
pub use env::{Env, EnvError, EnvSpec, ScriptedExpert, StepOutcome};
pub use expert::{
    ExpertEnv, ExpertError, ExpertFileError, ExpertMeta, ExpertPolicy, expert_path, experts_dir,
};
pub use humanoid::{Humanoid, HumanoidConfig};
pub use locomotion::LocoMode;
pub use pusher::{Pusher, PusherConfig};
pub use reacher::{Reacher, ReacherConfig};
pub use registry::{known_envs, make_env, make_env_in, make_plain_env, make_training_env};
pub use task::{TASK_PREFIX, TaskEnv, TaskFile};
pub use traj2d::{Traj2D, Traj2DConfig};
pub use walker2d::{Walker2d, Walker2dConfig};

pub use atomic::{AtomicFile, write_atomic};
