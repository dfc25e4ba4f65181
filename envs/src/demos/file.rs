//! The safetensors file format (module doc of [`super`], "File format"): atomic
//! save, checked load.

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use super::{
    DemoError, DemoMeta, DemoSplit, Demos, FILE_FORMAT, FORMAT, FORMAT_VERSION, SPLITS,
    UNKNOWN_MODE, UNSEALED_VERSION,
};

/// `v`'s little-endian bytes: the vector itself on a little-endian machine (a
/// 1M-transition import then saves without a copy of its data). `u32` modes and
/// episodes go out as I32 by bit pattern: [`UNKNOWN_MODE`] is -1; any other value above
/// `i32::MAX` comes out negative, which the loader rejects.
fn le_bytes<T: bytemuck::Pod>(v: &[T]) -> Cow<'_, [u8]> {
    let bytes: &[u8] = bytemuck::cast_slice(v);
    if cfg!(target_endian = "little") {
        Cow::Borrowed(bytes)
    } else {
        let w = std::mem::size_of::<T>();
        Cow::Owned(
            bytes
                .chunks(w)
                .flat_map(|c| c.iter().rev().copied())
                .collect(),
        )
    }
}

/// Builds the header metadata of a demos file from its meta JSON.
pub(super) fn header(meta_json: String) -> HashMap<String, String> {
    HashMap::from([
        ("format".to_owned(), FORMAT.to_owned()),
        ("format_version".to_owned(), FORMAT_VERSION.to_string()),
        ("meta".to_owned(), meta_json),
    ])
}

/// One tensor to write: name, dtype, shape, bytes.
pub(super) type RawTensor<'a> = (String, Dtype, Vec<usize>, Cow<'a, [u8]>);

pub(super) fn split_tensors<'a>(
    name: &str,
    s: &'a DemoSplit,
    meta: &DemoMeta,
) -> Vec<RawTensor<'a>> {
    let n = s.len();
    vec![
        (
            format!("{name}.obs"),
            Dtype::F32,
            vec![n, meta.obs_dim],
            le_bytes(&s.obs),
        ),
        (
            format!("{name}.act"),
            Dtype::F32,
            vec![n, meta.act_dim],
            le_bytes(&s.act),
        ),
        (
            format!("{name}.next_obs"),
            Dtype::F32,
            vec![n, meta.obs_dim],
            le_bytes(&s.next_obs),
        ),
        (
            format!("{name}.mode"),
            Dtype::I32,
            vec![n],
            le_bytes(&s.mode),
        ),
        (
            format!("{name}.episode"),
            Dtype::I32,
            vec![n],
            le_bytes(&s.episode),
        ),
        (
            format!("{name}.reward"),
            Dtype::F32,
            vec![n],
            le_bytes(&s.reward),
        ),
    ]
}

impl Demos {
    /// Writes the dataset to `path` atomically ([`crate::AtomicFile`]): a temporary
    /// file in the same directory is written tensor by tensor (no copy of the data in
    /// memory), synced and renamed over `path`, so no half-written file is ever seen.
    pub fn save(&self, path: &Path) -> Result<(), DemoError> {
        let ser_err = |reason: String| DemoError::Serialize {
            path: path.to_owned(),
            reason,
        };
        let meta = DemoMeta {
            format_version: FORMAT_VERSION,
            ..self.meta.clone()
        };
        let meta_json = serde_json::to_string(&meta).map_err(|e| ser_err(e.to_string()))?;
        let mut raw = split_tensors(SPLITS[0], &self.unlabeled, &self.meta);
        raw.extend(split_tensors(SPLITS[1], &self.labeled, &self.meta));
        let mut views = Vec::with_capacity(raw.len());
        for (name, dtype, shape, bytes) in &raw {
            let view = TensorView::new(*dtype, shape.clone(), bytes)
                .map_err(|e| ser_err(format!("tensor {name:?}: {e}")))?;
            views.push((name.clone(), view));
        }
        let file = crate::AtomicFile::new(path);
        std::fs::File::create(file.tmp()).map_err(|error| DemoError::Io {
            path: file.tmp().to_owned(),
            error,
        })?;
        let mut header = header(meta_json);
        ess_proto::checksum::seal(&mut header, views.iter().map(|(n, v)| (n.as_str(), v)));
        safetensors::serialize_to_file(views, Some(header), file.tmp())
            .map_err(|e| ser_err(e.to_string()))?;
        file.commit()
            .map_err(|(path, error)| DemoError::Io { path, error })?;
        tracing::debug!(path = %path.display(), rows = self.unlabeled.len() + self.labeled.len(), "saved demonstrations");
        Ok(())
    }

    /// Reads and fully validates a dataset written by [`Demos::save`].
    pub fn load(path: &Path) -> Result<Demos, DemoError> {
        let bytes = crate::read::read_regular(path).map_err(|error| DemoError::Io {
            path: path.to_owned(),
            error,
        })?;
        Self::from_bytes(&bytes, path)
    }

    /// Parses and validates safetensors bytes; `path` is only used in errors.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Demos, DemoError> {
        let p = || path.to_owned();
        let header_err = |error| DemoError::Header { path: p(), error };
        let file = ess_proto::checksum::open(bytes, FILE_FORMAT).map_err(header_err)?;
        let meta: DemoMeta =
            serde_json::from_str(file.get("meta").map_err(header_err)?).map_err(|e| {
                DemoError::BadMeta {
                    path: p(),
                    error: e.to_string(),
                }
            })?;
        validate_meta(&meta, path)?;
        let unlabeled = read_split(&file.tensors, SPLITS[0], &meta, path)?;
        let labeled = read_split(&file.tensors, SPLITS[1], &meta, path)?;
        let checks = [
            (
                "unlabeled_episodes_per_mode",
                &meta.unlabeled_episodes_per_mode,
                unlabeled.episodes_per_mode(meta.n_modes),
            ),
            (
                "unlabeled_steps_per_mode",
                &meta.unlabeled_steps_per_mode,
                unlabeled.steps_per_mode(meta.n_modes),
            ),
            (
                "labeled_steps_per_mode",
                &meta.labeled_steps_per_mode,
                labeled.steps_per_mode(meta.n_modes),
            ),
        ];
        for (field, in_meta, in_arrays) in checks {
            if *in_meta != in_arrays {
                return Err(DemoError::CountMismatch {
                    path: p(),
                    field,
                    in_meta: in_meta.clone(),
                    in_arrays,
                });
            }
        }
        Ok(Demos {
            meta,
            unlabeled,
            labeled,
        })
    }
}

fn validate_meta(meta: &DemoMeta, path: &Path) -> Result<(), DemoError> {
    let bad = |field: &'static str, value: String, reason: String| DemoError::BadMetaField {
        path: path.to_owned(),
        field,
        value,
        reason,
    };
    if !matches!(meta.format_version, UNSEALED_VERSION | FORMAT_VERSION) {
        return Err(DemoError::UnsupportedVersion {
            path: path.to_owned(),
            found: meta.format_version,
        });
    }
    for (field, value) in [
        ("obs_dim", meta.obs_dim),
        ("act_dim", meta.act_dim),
        ("n_modes", meta.n_modes),
    ] {
        if value == 0 {
            return Err(bad(field, "0".into(), "must be positive".into()));
        }
    }
    if meta.n_modes > i32::MAX as usize {
        return Err(bad(
            "n_modes",
            meta.n_modes.to_string(),
            "does not fit an I32 mode tensor".into(),
        ));
    }
    for (field, v) in [
        (
            "unlabeled_episodes_per_mode",
            &meta.unlabeled_episodes_per_mode,
        ),
        ("unlabeled_steps_per_mode", &meta.unlabeled_steps_per_mode),
        ("labeled_steps_per_mode", &meta.labeled_steps_per_mode),
    ] {
        if v.len() != meta.n_modes {
            return Err(bad(
                field,
                format!("{v:?}"),
                format!(
                    "has {} entries, expected n_modes = {}",
                    v.len(),
                    meta.n_modes
                ),
            ));
        }
    }
    Ok(())
}

/// Checks dtype and shape of `split.field` and returns its data bytes. `cols` is
/// `None` for a 1-D tensor `[rows]`, `Some(d)` for `[rows, d]`; `rows` is `None` when
/// this tensor defines the split's row count.
fn tensor_bytes<'a>(
    st: &SafeTensors<'a>,
    split: &'static str,
    field: &str,
    dtype: Dtype,
    rows: Option<usize>,
    cols: Option<usize>,
    path: &Path,
) -> Result<(usize, &'a [u8]), DemoError> {
    let tensor = format!("{split}.{field}");
    let view = st.tensor(&tensor).map_err(|_| DemoError::MissingTensor {
        path: path.to_owned(),
        tensor: tensor.clone(),
    })?;
    if view.dtype() != dtype {
        return Err(DemoError::WrongDtype {
            path: path.to_owned(),
            tensor,
            expected: format!("{dtype:?}"),
            got: format!("{:?}", view.dtype()),
        });
    }
    let shape = view.shape();
    let shape_ok = match cols {
        None => shape.len() == 1,
        Some(d) => shape.len() == 2 && shape[1] == d,
    };
    if !shape_ok {
        let expected = match cols {
            None => "[n]".to_owned(),
            Some(d) => format!("[n, {d}]"),
        };
        return Err(DemoError::WrongShape {
            path: path.to_owned(),
            tensor,
            expected,
            got: shape.to_vec(),
        });
    }
    let n = shape[0];
    if let Some(expected_rows) = rows
        && n != expected_rows
    {
        return Err(DemoError::RowCountMismatch {
            path: path.to_owned(),
            split,
            tensor,
            rows: n,
            expected_rows,
        });
    }
    Ok((n, view.data()))
}

fn decode_f32(bytes: &[u8], cols: usize, tensor: &str, path: &Path) -> Result<Vec<f32>, DemoError> {
    let v: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(DemoError::NonFinite {
            path: path.to_owned(),
            tensor: tensor.to_owned(),
            row: i / cols.max(1),
            value: v[i],
        });
    }
    Ok(v)
}

fn decode_i32(bytes: &[u8]) -> Vec<i32> {
    bytes
        .chunks_exact(4)
        .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn read_split(
    st: &SafeTensors<'_>,
    split: &'static str,
    meta: &DemoMeta,
    path: &Path,
) -> Result<DemoSplit, DemoError> {
    let name = |field: &str| format!("{split}.{field}");
    let (n, mode_bytes) = tensor_bytes(st, split, "mode", Dtype::I32, None, None, path)?;
    let rows = Some(n);
    let f32_tensor = |field: &str, cols: Option<usize>| -> Result<Vec<f32>, DemoError> {
        let (_, b) = tensor_bytes(st, split, field, Dtype::F32, rows, cols, path)?;
        decode_f32(b, cols.unwrap_or(1), &name(field), path)
    };
    let obs = f32_tensor("obs", Some(meta.obs_dim))?;
    let act = f32_tensor("act", Some(meta.act_dim))?;
    let next_obs = f32_tensor("next_obs", Some(meta.obs_dim))?;
    let reward = f32_tensor("reward", None)?;
    let (_, episode_bytes) = tensor_bytes(st, split, "episode", Dtype::I32, rows, None, path)?;

    let mut mode = Vec::with_capacity(n);
    for (row, v) in decode_i32(mode_bytes).into_iter().enumerate() {
        match u32::try_from(v) {
            Ok(m) if (m as usize) < meta.n_modes => mode.push(m),
            Err(_) if v == -1 && split == SPLITS[0] => mode.push(UNKNOWN_MODE),
            _ => {
                return Err(DemoError::ModeOutOfRange {
                    path: path.to_owned(),
                    tensor: name("mode"),
                    row,
                    value: i64::from(v),
                    n_modes: meta.n_modes,
                });
            }
        }
    }
    let mut episode = Vec::with_capacity(n);
    for (row, v) in decode_i32(episode_bytes).into_iter().enumerate() {
        let e = u32::try_from(v).map_err(|_| DemoError::NegativeEpisode {
            path: path.to_owned(),
            tensor: name("episode"),
            row,
            value: i64::from(v),
        })?;
        episode.push(e);
    }
    Ok(DemoSplit {
        obs,
        act,
        next_obs,
        mode,
        episode,
        reward,
    })
}
