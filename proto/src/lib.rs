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
//! - [`onnx`]: ONNX's own protobuf messages, for exporting policies.
//! - [`text`]: outside input quoted in error messages, control characters escaped.
//!
//! This crate depends on nothing internal and never on tch or MuJoCo.

pub mod checksum;
pub mod chunk;
pub mod config;
pub mod mlp;
pub mod shm;
pub mod text;
pub mod weights;

pub use chunk::{Chunk, Step, StepSink};
pub use config::{CheckedConfig, ConfigError, TrainConfig};
pub use mlp::Mlp;
pub use weights::{MlpLayout, WeightsError};

/// Messages of `proto/ess/v1/*.proto` (package `ess.v1`): the control plane's
/// `JobService` (its stubs with the `grpc` feature) and the MCAP run-log records.
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod pb {
    include!(concat!(env!("OUT_DIR"), "/ess.v1.rs"));
}

/// ONNX's protobuf schema (`proto/onnx/onnx.proto`, vendored from the onnx wheel):
/// the messages `ess export --onnx` writes a model with.
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod onnx {
    include!(concat!(env!("OUT_DIR"), "/onnx.rs"));
}

/// TensorBoard's event messages (`Event`, `Summary`, `TensorProto`; vendored unchanged
/// from tensorflow/tensorboard's `tensorboard/compat/proto`): what a run's
/// `tb/events.out.tfevents.*` files hold.
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod tensorboard {
    include!(concat!(env!("OUT_DIR"), "/tensorboard.rs"));
}

/// Foxglove's published schemas `foxglove.SceneUpdate` and `foxglove.FrameTransforms`
/// with what they import (vendored unchanged from foxglove/foxglove-sdk,
/// `schemas/proto/foxglove`): the run log's 3D scene of the robot.
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod foxglove {
    include!(concat!(env!("OUT_DIR"), "/foxglove.rs"));
}

/// The encoded `FileDescriptorSet` of [`foxglove`]'s files (and the
/// `google.protobuf` ones they import): the schema data of the run log's scene channels.
pub const FOXGLOVE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/foxglove_descriptor.bin"));

/// The encoded `FileDescriptorSet` of Ess's own `.proto` files (`ess.v1`): served by gRPC
/// reflection and embedded as the schema of protobuf channels in MCAP files.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/ess_descriptor.bin"));
