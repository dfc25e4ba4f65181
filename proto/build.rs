//! Compiles `proto/ess/v1/*.proto`, ONNX's `proto/onnx/onnx.proto`, TensorBoard's
//! event messages (`proto/tensorboard/compat/proto/event.proto`) and Foxglove's
//! `SceneUpdate` / `FrameTransforms` (`proto/foxglove/`) with the pure-Rust
//! `protox` (no `protoc` needed):
//! prost messages always; tonic client and server stubs with the `grpc` feature. The
//! encoded `FileDescriptorSet` is kept for gRPC reflection and for the protobuf
//! schemas embedded in MCAP run logs.

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = PathBuf::from("proto");
    let mut files: Vec<PathBuf> = std::fs::read_dir(root.join("ess/v1"))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "proto"))
        .collect();
    files.sort();
    println!("cargo:rerun-if-changed=proto");
    for f in &files {
        println!("cargo:rerun-if-changed={}", f.display());
    }
    let fds = protox::compile(&files, [&root])?;
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    std::fs::write(
        out.join("ess_descriptor.bin"),
        prost::Message::encode_to_vec(&fds),
    )?;
    let grpc = std::env::var_os("CARGO_FEATURE_GRPC").is_some();
    tonic_prost_build::configure()
        // `ess train --progress jsonl` writes it as JSON, one line per iteration.
        .type_attribute(
            ".ess.v1.IterationMetrics",
            "#[derive(serde::Serialize, serde::Deserialize)] #[serde(default)]",
        )
        .build_server(grpc)
        .build_client(grpc)
        .compile_fds(fds)?;
    // ONNX's own schema (vendored from the onnx wheel), for `ess export --onnx`.
    messages_only(protox::compile([root.join("onnx/onnx.proto")], [&root])?)?;
    // TensorBoard's own Event / Summary messages (vendored from tensorflow/tensorboard),
    // for the run's event files (`ess_learner::tboard`).
    let tb = protox::compile([root.join("tensorboard/compat/proto/event.proto")], [&root])?;
    messages_only(tb)?;
    // Foxglove's published schemas (vendored from foxglove/foxglove-sdk) for the run
    // log's 3D scene; their descriptor set is the MCAP channels' schema data.
    let fox = protox::compile(
        [
            root.join("foxglove/SceneUpdate.proto"),
            root.join("foxglove/FrameTransforms.proto"),
        ],
        [&root],
    )?;
    std::fs::write(
        out.join("foxglove_descriptor.bin"),
        prost::Message::encode_to_vec(&fox),
    )?;
    messages_only(fox)?;
    Ok(())
}

/// prost messages of an outside schema, no gRPC stubs.
fn messages_only(fds: prost_types::FileDescriptorSet) -> std::io::Result<()> {
    tonic_prost_build::configure()
        .build_server(false)
        .build_client(false)
        .compile_fds(fds)
}
