//! `ess-proto`: every contract between Ess processes and on disk.
//!
//! - [`config`]: the training configuration (serde TOML, `deny_unknown_fields`), its
//!   layering (defaults < preset < file < `--set k=v`) and its validation into a
//!   [`config::CheckedConfig`]. Defaults state the paper's values.
//! - [`weights`]: the flat `f32` layout of an MLP's parameters, shared by the learner
//!   (which exports them) and the actors (which run the pure-Rust forward pass).
//! - [`mlp`]: the pure-Rust forward pass over such weights.
//! - [`chunk`]: the transition chunk an actor hands the learner.
//! - [`shm`]: the `#[repr(C)]` shared-memory layouts of chunks and weights.
//!
//! This crate depends on nothing internal and never on tch or MuJoCo.

pub mod chunk;
pub mod config;
pub mod mlp;
pub mod shm;
pub mod weights;

pub use chunk::{Chunk, Step, StepSink};
pub use config::{CheckedConfig, ConfigError, TrainConfig};
pub use mlp::Mlp;
pub use weights::{MlpLayout, WeightsError};
