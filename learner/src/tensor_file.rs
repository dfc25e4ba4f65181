//! The learner's safetensors files (checkpoints, expert training states, SAC replay
//! buffers): libtorch tensors written atomically with the checksums of
//! [`ess_proto::checksum`], and read back only when every tensor matches them.
//!
//! tch's own `VarStore::save` / `Tensor::write_safetensors` write no metadata, so a
//! flipped byte in a checkpoint loaded silently; every learner file goes through here.

use ess_proto::checksum::{self, ChecksumError};
use safetensors::tensor::{Dtype, TensorView};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use tch::{Device, Kind, Tensor, nn};

/// A tensor file that cannot be written or read back.
#[derive(Debug, thiserror::Error)]
pub enum TensorFileError {
    /// Reading or writing failed.
    #[error("{}: {error}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// Corrupt, cut, or without checksums.
    #[error("{}: {error}", path.display())]
    Checksum {
        /// The file.
        path: PathBuf,
        /// Which tensor.
        error: ChecksumError,
    },
    /// A file whose checksum another file holds does not match it (a checkpoint's
    /// `state.json` against `state.sha256`).
    #[error("{}: does not match its checksum in {}: the file is corrupt", path.display(), sums.display())]
    Mismatch {
        /// The file.
        path: PathBuf,
        /// The file holding its checksum.
        sums: PathBuf,
    },
    /// A tensor safetensors or this module cannot carry.
    #[error("{}: tensor `{name}`: {reason}", path.display())]
    Tensor {
        /// The file.
        path: PathBuf,
        /// The tensor.
        name: String,
        /// Why.
        reason: String,
    },
}

impl TensorFileError {
    /// A corrupt file (bad input: exit 2), rather than a failure to read or write.
    pub fn is_corrupt(&self) -> bool {
        matches!(self, Self::Checksum { .. } | Self::Mismatch { .. })
    }
}

/// The safetensors dtype of a libtorch kind, and its element size.
fn dtype_of(kind: Kind) -> Option<Dtype> {
    Some(match kind {
        Kind::Float => Dtype::F32,
        Kind::Double => Dtype::F64,
        Kind::Half => Dtype::F16,
        Kind::BFloat16 => Dtype::BF16,
        Kind::Int64 => Dtype::I64,
        Kind::Int => Dtype::I32,
        Kind::Int16 => Dtype::I16,
        Kind::Int8 => Dtype::I8,
        Kind::Uint8 => Dtype::U8,
        Kind::Bool => Dtype::BOOL,
        _ => return None,
    })
}

fn kind_of(dtype: Dtype) -> Option<Kind> {
    [
        Kind::Float,
        Kind::Double,
        Kind::Half,
        Kind::BFloat16,
        Kind::Int64,
        Kind::Int,
        Kind::Int16,
        Kind::Int8,
        Kind::Uint8,
        Kind::Bool,
    ]
    .into_iter()
    .find(|&k| dtype_of(k) == Some(dtype))
}

/// A tensor's dtype, shape and bytes (copied off the device, made contiguous).
fn raw(
    path: &Path,
    name: &str,
    t: &Tensor,
) -> Result<(Dtype, Vec<usize>, Vec<u8>), TensorFileError> {
    let bad = |reason: String| TensorFileError::Tensor {
        path: path.to_path_buf(),
        name: name.to_string(),
        reason,
    };
    let t = t.to_device(Device::Cpu).contiguous();
    let dtype = dtype_of(t.kind()).ok_or_else(|| bad(format!("kind {:?}", t.kind())))?;
    let numel = t.numel();
    let mut bytes = vec![0u8; numel * t.kind().elt_size_in_bytes()];
    t.f_copy_data_u8(&mut bytes, numel)
        .map_err(|e| bad(e.to_string()))?;
    let shape = t.size().iter().map(|&d| d as usize).collect();
    Ok((dtype, shape, bytes))
}

/// Writes `named` (and the `metadata` entries) to `path` atomically, sealed.
pub fn save<S: AsRef<str>>(
    path: &Path,
    named: &[(S, Tensor)],
    mut metadata: HashMap<String, String>,
) -> Result<(), TensorFileError> {
    let raws = named
        .iter()
        .map(|(n, t)| raw(path, n.as_ref(), t))
        .collect::<Result<Vec<_>, _>>()?;
    let mut views = Vec::with_capacity(raws.len());
    for ((n, _), (dtype, shape, bytes)) in named.iter().zip(&raws) {
        let view =
            TensorView::new(*dtype, shape.clone(), bytes).map_err(|e| TensorFileError::Tensor {
                path: path.to_path_buf(),
                name: n.as_ref().to_string(),
                reason: e.to_string(),
            })?;
        views.push((n.as_ref(), view));
    }
    checksum::seal(&mut metadata, views.iter().map(|(n, v)| (*n, v)));
    // Streamed tensor by tensor into the temporary file (no second copy of the data).
    let file = ess_envs::AtomicFile::new(path);
    safetensors::serialize_to_file(views, Some(metadata), file.tmp()).map_err(|e| match e {
        // Named by the file being written, not its temporary name.
        safetensors::SafeTensorError::IoError(error) => TensorFileError::Io {
            path: path.to_path_buf(),
            error,
        },
        other => TensorFileError::Tensor {
            path: path.to_path_buf(),
            name: String::new(),
            reason: other.to_string(),
        },
    })?;
    file.commit()
        .map_err(|(path, error)| TensorFileError::Io { path, error })
}

/// A sealed file's tensors (on the CPU) and its other metadata entries; refused when
/// anything differs from its checksums, or it has none.
pub type Contents = (HashMap<String, Tensor>, HashMap<String, String>);

/// Reads what [`save`] wrote.
pub fn load(path: &Path) -> Result<Contents, TensorFileError> {
    let bytes = std::fs::read(path).map_err(|error| TensorFileError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    let corrupt = |error| TensorFileError::Checksum {
        path: path.to_path_buf(),
        error,
    };
    checksum::verify(&bytes, false).map_err(corrupt)?;
    let layout = |e: safetensors::SafeTensorError| corrupt(ChecksumError::Layout(e.to_string()));
    let st = safetensors::SafeTensors::deserialize(&bytes).map_err(layout)?;
    let (_, md) = safetensors::SafeTensors::read_metadata(&bytes).map_err(layout)?;
    let mut metadata = md.metadata().clone().unwrap_or_default();
    metadata.remove(checksum::KEY);
    let mut tensors = HashMap::new();
    for (name, view) in st.tensors() {
        let kind = kind_of(view.dtype()).ok_or_else(|| TensorFileError::Tensor {
            path: path.to_path_buf(),
            name: name.clone(),
            reason: format!("dtype {:?}", view.dtype()),
        })?;
        let shape: Vec<i64> = view.shape().iter().map(|&d| d as i64).collect();
        tensors.insert(name, Tensor::from_data_size(view.data(), &shape, kind));
    }
    Ok((tensors, metadata))
}

/// Writes every variable of `vs` to `path` (sealed), as `VarStore::save` names them.
pub fn save_var_store(vs: &nn::VarStore, path: &Path) -> Result<(), TensorFileError> {
    let mut named: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    save(path, &named, HashMap::new())
}

/// Loads `path` into `vs`: the tensors [`load`] checked against their checksums (one
/// read of the file), every variable of `vs` by name, shapes as they are.
pub fn load_var_store(vs: &mut nn::VarStore, path: &Path) -> anyhow::Result<()> {
    use anyhow::Context;
    let (mut tensors, _) = load(path)?;
    for (name, mut var) in vs.variables() {
        let src = tensors
            .remove(&name)
            .with_context(|| format!("{}: no tensor `{name}`", path.display()))?;
        if src.size() != var.size() {
            anyhow::bail!(
                "{}: tensor `{name}` has shape {:?}, the network's is {:?}",
                path.display(),
                src.size(),
                var.size()
            );
        }
        tch::no_grad(|| var.f_copy_(&src.to_device(var.device())))
            .with_context(|| format!("{}: tensor `{name}`", path.display()))?;
    }
    Ok(())
}

/// SHA-256 (hex) of `bytes`, for a JSON file whose checksum a sealed file carries.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    checksum::hex(sha2::Sha256::digest(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tensors_of_every_kind_round_trip_and_a_flipped_byte_names_its_tensor() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.safetensors");
        let named = [
            ("a", Tensor::from_slice(&[1.5f32, -2.0, 3.25]).view([3, 1])),
            ("b", Tensor::from_slice(&[7i64, 8])),
            ("c", Tensor::from_slice(&[0.125f64])),
        ];
        let md = HashMap::from([("note".to_string(), "x".to_string())]);
        save(&p, &named, md.clone()).unwrap();
        let (t, got_md) = load(&p).unwrap();
        assert_eq!(got_md, md);
        for (n, want) in &named {
            assert!(t[*n].equal(want), "{n}");
            assert_eq!(t[*n].kind(), want.kind(), "{n}");
        }
        let mut bytes = std::fs::read(&p).unwrap();
        let n = bytes.len();
        bytes[n - 2] ^= 0x10; // inside the last tensor laid out (`a`: 4-byte dtype after 8-byte ones)
        std::fs::write(&p, &bytes).unwrap();
        let e = load(&p).unwrap_err().to_string();
        assert!(e.contains("t.safetensors") && e.contains("`a`"), "{e}");
    }

    #[test]
    fn a_file_tch_wrote_without_checksums_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("plain.safetensors");
        Tensor::write_safetensors(&[("a", Tensor::from_slice(&[1f32]))], &p).unwrap();
        let e = load(&p).unwrap_err().to_string();
        assert!(e.contains("no `ess.sha256` checksums"), "{e}");
    }
}
