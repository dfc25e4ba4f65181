//! NumPy `.npz` demonstrations (read with the `npyz` crate).
//!
//! Arrays, all C-ordered, float arrays `float32` or `float64` (converted to `float32`):
//!
//! | name                | shape           | required |
//! |---------------------|-----------------|----------|
//! | `observations`      | `[N, obs_dim]`  | yes      |
//! | `actions`           | `[N, act_dim]`  | yes      |
//! | `episode_ends`      | `[E]` int       | one of the two boundary forms: exclusive end row of each episode, increasing, the last `N` |
//! | `terminals`, `timeouts` | `[N]` bool  | or: D4RL's form, an episode ends at a row where either is true (and at row `N - 1`) |
//! | `next_observations` | `[N, obs_dim]`  | no: without it each episode's last step is dropped (it has no next observation) |
//! | `rewards`           | `[N]`           | no (0 when absent) |
//! | `episode_modes`     | `[E]` int       | no: per-episode mode labels, -1 unknown (another name with `--labels-field`) |

use std::path::Path;

use npyz::npz::NpzArchive;
use npyz::{DType, NpyFile, Order};

use super::{Builder, Episode, ImportError};

type Archive = NpzArchive<std::io::BufReader<std::fs::File>>;

/// One array: its shape and values.
struct Array<T> {
    shape: Vec<usize>,
    data: Vec<T>,
}

fn read_err(path: &Path, reason: String) -> ImportError {
    ImportError::Read {
        path: path.to_owned(),
        reason,
    }
}

fn type_of(npy: &NpyFile<impl std::io::Read>) -> String {
    match npy.dtype() {
        DType::Plain(t) => t.to_string(),
        other => format!("{other:?}"),
    }
}

fn open_array<'a>(
    z: &'a mut Archive,
    path: &Path,
    name: &str,
) -> Result<Option<NpyFile<impl std::io::Read + 'a>>, ImportError> {
    let npy = z
        .by_name(name)
        .map_err(|e| read_err(path, format!("array {name:?}: {e}")))?;
    if let Some(n) = &npy
        && n.order() == Order::Fortran
    {
        return Err(read_err(
            path,
            format!("array {name:?} is Fortran-ordered; save it C-ordered (np.ascontiguousarray)"),
        ));
    }
    Ok(npy)
}

fn shape(npy: &NpyFile<impl std::io::Read>) -> Vec<usize> {
    npy.shape().iter().map(|&d| d as usize).collect()
}

/// A float array as `f32`.
fn floats(z: &mut Archive, path: &Path, name: &str) -> Result<Option<Array<f32>>, ImportError> {
    let Some(npy) = open_array(z, path, name)? else {
        return Ok(None);
    };
    let (shape, ty) = (shape(&npy), type_of(&npy));
    let bad = |e: std::io::Error| read_err(path, format!("array {name:?} ({ty}): {e}"));
    let data = match &ty[1..] {
        "f4" => npy.into_vec::<f32>().map_err(bad)?,
        "f8" => npy
            .into_vec::<f64>()
            .map_err(bad)?
            .into_iter()
            .map(|x| x as f32)
            .collect(),
        _ => {
            return Err(read_err(
                path,
                format!("array {name:?} has dtype {ty}, expected float32 or float64"),
            ));
        }
    };
    Ok(Some(Array { shape, data }))
}

/// An integer or boolean array as `i64`.
fn ints(z: &mut Archive, path: &Path, name: &str) -> Result<Option<Array<i64>>, ImportError> {
    let Some(npy) = open_array(z, path, name)? else {
        return Ok(None);
    };
    let (shape, ty) = (shape(&npy), type_of(&npy));
    let bad = |e: std::io::Error| read_err(path, format!("array {name:?} ({ty}): {e}"));
    let data: Vec<i64> = match &ty[1..] {
        "i8" => npy.into_vec::<i64>().map_err(bad)?,
        "i4" => npy
            .into_vec::<i32>()
            .map_err(bad)?
            .into_iter()
            .map(i64::from)
            .collect(),
        "u4" => npy
            .into_vec::<u32>()
            .map_err(bad)?
            .into_iter()
            .map(i64::from)
            .collect(),
        "u8" => npy
            .into_vec::<u64>()
            .map_err(bad)?
            .into_iter()
            .map(|x| i64::try_from(x).unwrap_or(i64::MAX))
            .collect(),
        "b1" => npy
            .into_vec::<bool>()
            .map_err(bad)?
            .into_iter()
            .map(i64::from)
            .collect(),
        _ => {
            return Err(read_err(
                path,
                format!("array {name:?} has dtype {ty}, expected an integer or bool type"),
            ));
        }
    };
    Ok(Some(Array { shape, data }))
}

fn required<T>(a: Option<T>, path: &Path, name: &str, z: &Archive) -> Result<T, ImportError> {
    a.ok_or_else(|| {
        let have: Vec<&str> = z.array_names().collect();
        read_err(
            path,
            format!(
                "array {name:?} is missing (the file has: {})",
                have.join(", ")
            ),
        )
    })
}

/// The exclusive end row of each episode.
fn episode_ends(z: &mut Archive, path: &Path, n: usize) -> Result<Vec<usize>, ImportError> {
    let invalid = |what: String| ImportError::Invalid {
        path: path.to_owned(),
        what,
    };
    if let Some(ends) = ints(z, path, "episode_ends")? {
        let mut prev = 0usize;
        let mut out = Vec::with_capacity(ends.data.len());
        for (e, &end) in ends.data.iter().enumerate() {
            match usize::try_from(end) {
                Ok(end) if end > prev && end <= n => {
                    out.push(end);
                    prev = end;
                }
                _ => {
                    return Err(invalid(format!(
                        "episode_ends[{e}] = {end}: ends must increase strictly from 1 up to N = {n} (an empty episode?)"
                    )));
                }
            }
        }
        if prev != n {
            return Err(invalid(format!(
                "episode_ends: the last end is {prev}, expected N = {n}"
            )));
        }
        return Ok(out);
    }
    let t = ints(z, path, "terminals")?;
    let o = ints(z, path, "timeouts")?;
    if t.is_none() && o.is_none() {
        return Err(invalid(
            "no episode boundaries: give episode_ends, or terminals / timeouts".into(),
        ));
    }
    let mut out = Vec::new();
    for row in 0..n {
        let at = |a: &Option<Array<i64>>| {
            a.as_ref()
                .is_some_and(|a| a.data.get(row).is_some_and(|&x| x != 0))
        };
        if at(&t) || at(&o) || row + 1 == n {
            out.push(row + 1);
        }
    }
    Ok(out)
}

/// Reads `path` into `b`; `labels_field` names the per-episode label array (default
/// `episode_modes`, used when present), `side_labels` are labels from a side file.
pub fn read(
    path: &Path,
    b: &mut Builder,
    labels_field: Option<&str>,
    side_labels: Option<&[Option<i64>]>,
) -> Result<(), ImportError> {
    let mut z =
        NpzArchive::open(path).map_err(|e| read_err(path, format!("not a readable .npz: {e}")))?;
    let obs = floats(&mut z, path, "observations")?;
    let obs = required(obs, path, "observations", &z)?;
    let act = floats(&mut z, path, "actions")?;
    let act = required(act, path, "actions", &z)?;
    let next = floats(&mut z, path, "next_observations")?;
    let rewards = floats(&mut z, path, "rewards")?;
    let n = obs.shape.first().copied().unwrap_or(0);
    let ends = episode_ends(&mut z, path, n)?;
    let invalid = |what: String| ImportError::Invalid {
        path: path.to_owned(),
        what,
    };
    let check_rows = |name: &str, shape: &[usize]| {
        if shape.first() != Some(&n) {
            return Err(invalid(format!(
                "{name} has shape {shape:?}, expected {n} rows like observations"
            )));
        }
        Ok(())
    };
    check_rows("actions", &act.shape)?;
    let (od, ad) = b.dims();
    for (name, a, want) in [("observations", &obs, od), ("actions", &act, ad)] {
        let w = super::row_width(&a.shape);
        if a.shape.len() != 2 || w != want {
            return Err(invalid(format!(
                "{name} has shape {:?}: width {w}, but the env's is {want}",
                a.shape
            )));
        }
    }
    for (name, a) in [("next_observations", &next), ("rewards", &rewards)] {
        if let Some(a) = a {
            check_rows(name, &a.shape)?;
        }
    }
    let field = labels_field.unwrap_or("episode_modes");
    let labels = match ints(&mut z, path, field)? {
        Some(l) if l.data.len() == ends.len() => Some(l.data),
        Some(l) => {
            return Err(invalid(format!(
                "{field} has {} entries for {} episodes",
                l.data.len(),
                ends.len()
            )));
        }
        None if labels_field.is_some() => {
            return Err(required(None::<()>, path, field, &z).unwrap_err());
        }
        None => None,
    };
    if let Some(s) = side_labels
        && s.len() != ends.len()
    {
        return Err(invalid(format!(
            "the labels file has {} entries for {} episodes",
            s.len(),
            ends.len()
        )));
    }
    b.reserve(n);
    push_episodes(b, &obs, &act, next.as_ref(), rewards.as_ref(), &ends, |e| {
        side_labels.map_or_else(|| labels.as_ref().map(|l| l[e]), |s| s[e])
    })
}

fn push_episodes(
    b: &mut Builder,
    obs: &Array<f32>,
    act: &Array<f32>,
    next: Option<&Array<f32>>,
    rewards: Option<&Array<f32>>,
    ends: &[usize],
    label: impl Fn(usize) -> Option<i64>,
) -> Result<(), ImportError> {
    let (od, ad) = b.dims();
    let mut start = 0;
    for (e, &end) in ends.iter().enumerate() {
        // Without next_observations the last step has no next observation: dropped.
        let stop = if next.is_some() { end } else { end - 1 };
        b.push(Episode {
            name: format!("episode {e} (rows {start}..{end})"),
            obs: &obs.data[start * od..end * od],
            next_obs: next.map(|x| &x.data[start * od..end * od]),
            act: &act.data[start * ad..stop * ad],
            reward: rewards.map(|r| &r.data[start..stop]),
            label: label(e),
        })?;
        start = end;
    }
    Ok(())
}
