//! Minari datasets (the Farama Foundation's layout), read with `hdf5-metno` (a static
//! HDF5 built from source, so users need no system package).
//!
//! A dataset directory holds `data/main_data.hdf5` and `data/metadata.json`; the HDF5
//! file has one group `episode_<id>` per episode with `observations` (`[n + 1, obs_dim]`:
//! the final observation included), `actions` (`[n, act_dim]`), `rewards`,
//! `terminations`, `truncations` and `infos`. Episodes are read in id order. Only Box
//! observation and action spaces are supported (a Dict space is a group, refused by
//! name). Labels: `--labels-field F` reads `F` in each episode group, a dataset
//! (per-step, must be constant over the episode, e.g. `infos/mode`) or an attribute
//! (e.g. `options/mode`, the reset options Minari records).

use std::path::{Path, PathBuf};

use hdf5::{File, Group};

use super::{Builder, Episode, ImportError};

fn read_err(path: &Path, reason: impl Into<String>) -> ImportError {
    ImportError::Read {
        path: path.to_owned(),
        reason: reason.into(),
    }
}

/// The `main_data.hdf5` of a dataset given as its directory, its `data` directory or
/// the file itself.
pub fn data_file(path: &Path) -> Result<PathBuf, ImportError> {
    if path.is_file() {
        return Ok(path.to_owned());
    }
    for cand in [
        path.join("data/main_data.hdf5"),
        path.join("main_data.hdf5"),
    ] {
        if cand.is_file() {
            return Ok(cand);
        }
    }
    Err(read_err(
        path,
        "not a Minari dataset: no data/main_data.hdf5 in it (and not a file)",
    ))
}

/// `metadata.json` beside the data file, when present.
pub fn metadata(data: &Path) -> Result<Option<serde_json::Value>, ImportError> {
    let meta = data.with_file_name("metadata.json");
    if !meta.is_file() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&meta).map_err(|e| read_err(&meta, e.to_string()))?;
    serde_json::from_str(&text)
        .map(Some)
        .map_err(|e| read_err(&meta, format!("not valid JSON: {e}")))
}

/// The episode groups in id order.
fn episode_names(file: &File, path: &Path) -> Result<Vec<String>, ImportError> {
    let names = file
        .member_names()
        .map_err(|e| read_err(path, e.to_string()))?;
    let mut eps: Vec<(u64, String)> = Vec::new();
    for n in names {
        if let Some(id) = n.strip_prefix("episode_").and_then(|s| s.parse().ok()) {
            eps.push((id, n));
        }
    }
    eps.sort();
    Ok(eps.into_iter().map(|(_, n)| n).collect())
}

fn floats(
    g: &Group,
    ep: &str,
    field: &str,
    path: &Path,
) -> Result<(Vec<usize>, Vec<f32>), ImportError> {
    let invalid = |what: String| ImportError::Invalid {
        path: path.to_owned(),
        what,
    };
    if g.group(field).is_ok() {
        return Err(invalid(format!(
            "{ep}: {field} is a group (a Dict or Tuple space); only Box spaces can be imported"
        )));
    }
    let ds = g
        .dataset(field)
        .map_err(|e| invalid(format!("{ep}: {field}: {e}")))?;
    let data = ds
        .read_raw::<f32>()
        .map_err(|e| invalid(format!("{ep}: {field}: {e}")))?;
    Ok((ds.shape(), data))
}

/// The episode's label from `field`: a constant per-step dataset or a scalar attribute.
fn label(g: &Group, ep: &str, field: &str, path: &Path) -> Result<Option<i64>, ImportError> {
    let invalid = |what: String| ImportError::Invalid {
        path: path.to_owned(),
        what,
    };
    if let Ok(ds) = g.dataset(field) {
        let v = ds
            .read_raw::<i64>()
            .map_err(|e| invalid(format!("{ep}: {field}: {e}")))?;
        let first = *v
            .first()
            .ok_or_else(|| invalid(format!("{ep}: {field} is empty")))?;
        if let Some(row) = v.iter().position(|&x| x != first) {
            return Err(invalid(format!(
                "{ep}: {field} changes within the episode (row 0: {first}, row {row}: {}); a label is per episode",
                v[row]
            )));
        }
        return Ok(Some(first));
    }
    match g.attr(field) {
        Ok(a) => a
            .read_scalar::<i64>()
            .map(Some)
            .map_err(|e| invalid(format!("{ep}: attribute {field}: {e}"))),
        Err(_) => Err(invalid(format!(
            "{ep}: no dataset or attribute {field:?} to read labels from"
        ))),
    }
}

/// Reads the dataset at `path` into `b`; returns the number of episodes.
pub fn read(
    path: &Path,
    b: &mut Builder,
    labels_field: Option<&str>,
    side_labels: Option<&[Option<i64>]>,
) -> Result<usize, ImportError> {
    let data = data_file(path)?;
    let file =
        File::open(&data).map_err(|e| read_err(&data, format!("not a readable HDF5 file: {e}")))?;
    let names = episode_names(&file, &data)?;
    let invalid = |what: String| ImportError::Invalid {
        path: data.clone(),
        what,
    };
    let meta = metadata(&data)?;
    let count = |key: &str| {
        meta.as_ref()
            .and_then(|m| m.get(key).and_then(|t| t.as_u64()))
    };
    if let Some(steps) = count("total_steps") {
        b.reserve(steps as usize);
    }
    if let Some(total) = count("total_episodes")
        && total as usize != names.len()
    {
        return Err(invalid(format!(
            "metadata.json says total_episodes = {total} but the file holds {} episode groups (a cut copy?)",
            names.len()
        )));
    }
    if let Some(s) = side_labels
        && s.len() != names.len()
    {
        return Err(invalid(format!(
            "the labels file has {} entries for {} episodes",
            s.len(),
            names.len()
        )));
    }
    let (od, ad) = b.dims();
    for (e, ep) in names.iter().enumerate() {
        let g = file.group(ep).map_err(|x| invalid(format!("{ep}: {x}")))?;
        let (os, obs) = floats(&g, ep, "observations", &data)?;
        let (asz, act) = floats(&g, ep, "actions", &data)?;
        for (field, shape, want) in [("observations", &os, od), ("actions", &asz, ad)] {
            let w = super::row_width(shape);
            if w != want {
                return Err(invalid(format!(
                    "{ep}: {field} has shape {shape:?}: width {w}, but the env's is {want}"
                )));
            }
        }
        let reward = match g.dataset("rewards") {
            Ok(ds) => Some(
                ds.read_raw::<f32>()
                    .map_err(|x| invalid(format!("{ep}: rewards: {x}")))?,
            ),
            Err(_) => None,
        };
        let label = match (side_labels, labels_field) {
            (Some(s), _) => s[e],
            (None, Some(f)) => label(&g, ep, f, &data)?,
            (None, None) => None,
        };
        b.push(Episode {
            name: ep.clone(),
            obs: &obs,
            next_obs: None,
            act: &act,
            reward: reward.as_deref(),
            label,
        })?;
    }
    Ok(names.len())
}
