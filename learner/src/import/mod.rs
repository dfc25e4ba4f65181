//! `ess demos import`: demonstrations recorded elsewhere (a Minari dataset, a NumPy
//! `.npz`) into Ess's demonstration file ([`ess_envs::demos`]).
//!
//! The readers ([`minari`], [`npz`]) only turn their format into episodes pushed into
//! a [`Builder`]; the builder checks every value (widths, finiteness, empty episodes,
//! labels) and makes the two splits:
//!
//! - **unlabeled**: every imported episode, in source order; `mode` is the episode's
//!   label where the source has one (for analysis and full-label baselines only) and
//!   unknown (-1) otherwise.
//! - **labeled**: for each mode, whole labeled episodes of that mode (seeded shuffle of
//!   the labeled ones) until `ceil(label_ratio * unlabeled_steps / n_modes)` steps, the
//!   last one cut: the same balanced rule as generated datasets. These rows are copies:
//!   in semi-supervised learning the labeled demonstrations are part of the data.
//!
//! Provenance (format, path, SHA-256 of the data file, the options) goes into the
//! file's metadata ([`ess_envs::demos::DemoSource`]).

pub mod minari;
pub mod npz;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use ess_envs::demos::{DemoMeta, DemoSource, DemoSplit, Demos, UNKNOWN_MODE};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use sha2::Digest;

/// Errors of an import; every one names the source file and, where it applies, the
/// episode, field and row.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The source cannot be read.
    #[error("{}: {reason}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// What failed.
        reason: String,
    },
    /// The source's content is unfit (width, value, label, ...).
    #[error("{}: {what}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong, naming the episode / field / row.
        what: String,
    },
    /// The options do not fit the data (label ratio, modes).
    #[error("{}: {what}", path.display())]
    Options {
        /// The source file.
        path: PathBuf,
        /// What does not fit.
        what: String,
    },
}

/// What the import is asked for.
#[derive(Debug, Clone)]
pub struct ImportOptions {
    /// Env name recorded in the file (a built-in name or `task:PATH`).
    pub env: String,
    /// The env's observation and action widths, which every episode must have.
    pub dims: (usize, usize),
    /// The env's episode length.
    pub episode_len: usize,
    /// Number of modes; `None`: one past the largest label.
    pub n_modes: Option<usize>,
    /// Labeled steps as a fraction of all steps, in (0, 1].
    pub label_ratio: f64,
    /// Seed of the labeled episodes' choice.
    pub seed: u64,
    /// Options recorded as provenance (label source, ...), beside the ones above.
    pub extra: BTreeMap<String, String>,
}

/// One episode as a reader hands it over. `obs` has `n` rows, or `n + 1` when the
/// source stores the final observation (Minari); `next_obs` (n rows) is only given
/// when the source stores it separately.
pub struct Episode<'a> {
    /// Where it is in the source (`episode_12`, `episode 3`), for messages.
    pub name: String,
    /// Observations, row-major.
    pub obs: &'a [f32],
    /// Next observations, when stored separately.
    pub next_obs: Option<&'a [f32]>,
    /// Actions, row-major.
    pub act: &'a [f32],
    /// Per-step rewards, when stored.
    pub reward: Option<&'a [f32]>,
    /// The episode's mode label (`None`: unknown).
    pub label: Option<i64>,
}

/// Collects checked episodes and builds the [`Demos`].
pub struct Builder {
    path: PathBuf,
    opts: ImportOptions,
    split: DemoSplit,
    labels: Vec<Option<u32>>,
    ranges: Vec<(usize, usize)>,
}

fn finite(name: &str, field: &str, v: &[f32], width: usize) -> Result<(), String> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(i) => Err(format!(
            "{name}: {field} row {} holds a non-finite value {}",
            i / width.max(1),
            v[i]
        )),
        None => Ok(()),
    }
}

impl Builder {
    /// An empty import of `path` with `opts`.
    pub fn new(path: &Path, opts: ImportOptions) -> Self {
        Self {
            path: path.to_owned(),
            opts,
            split: DemoSplit::default(),
            labels: Vec::new(),
            ranges: Vec::new(),
        }
    }

    /// Reserves room for `rows` transitions, when the source says how many it holds
    /// (growing by doubling would hold up to three times the data at a reallocation).
    pub fn reserve(&mut self, rows: usize) {
        let (od, ad) = self.opts.dims;
        let s = &mut self.split;
        s.obs.reserve_exact(rows * od);
        s.next_obs.reserve_exact(rows * od);
        s.act.reserve_exact(rows * ad);
        s.reward.reserve_exact(rows);
        s.mode.reserve_exact(rows);
        s.episode.reserve_exact(rows);
    }

    /// The env's observation and action widths.
    pub fn dims(&self) -> (usize, usize) {
        self.opts.dims
    }

    fn invalid(&self, what: String) -> ImportError {
        ImportError::Invalid {
            path: self.path.clone(),
            what,
        }
    }

    /// Checks and appends one episode.
    pub fn push(&mut self, ep: Episode<'_>) -> Result<(), ImportError> {
        let (od, ad) = self.opts.dims;
        let name = &ep.name;
        let width = |field: &str, len: usize, w: usize, what: &str| {
            if len.is_multiple_of(w) {
                Ok(len / w)
            } else {
                Err(format!(
                    "{name}: {field} has {len} values, not a whole number of rows of {what} = {w}"
                ))
            }
        };
        let n =
            width("actions", ep.act.len(), ad, "the env's act_dim").map_err(|e| self.invalid(e))?;
        let obs_rows = width("observations", ep.obs.len(), od, "the env's obs_dim")
            .map_err(|e| self.invalid(e))?;
        if n == 0 {
            return Err(self.invalid(format!("{name}: the episode is empty (no actions)")));
        }
        let want_obs = if ep.next_obs.is_some() { n } else { n + 1 };
        if obs_rows != want_obs {
            return Err(self.invalid(format!(
                "{name}: observations has {obs_rows} rows for {n} actions, expected {want_obs} \
                 (obs width {od}, act width {ad}: do they match the env's?)"
            )));
        }
        let check = || -> Result<(), String> {
            finite(name, "observations", ep.obs, od)?;
            finite(name, "actions", ep.act, ad)?;
            if let Some(no) = ep.next_obs {
                if no.len() != n * od {
                    return Err(format!(
                        "{name}: next_observations has {} values, expected {}",
                        no.len(),
                        n * od
                    ));
                }
                finite(name, "next_observations", no, od)?;
            }
            if let Some(r) = ep.reward {
                if r.len() != n {
                    return Err(format!(
                        "{name}: rewards has {} rows, expected {n}",
                        r.len()
                    ));
                }
                finite(name, "rewards", r, 1)?;
            }
            Ok(())
        };
        check().map_err(|e| self.invalid(e))?;
        let label = self.label(name, ep.label)?;
        let index = u32::try_from(self.ranges.len()).unwrap_or(u32::MAX);
        let start = self.split.len();
        let s = &mut self.split;
        s.obs.extend_from_slice(&ep.obs[..n * od]);
        match ep.next_obs {
            Some(no) => s.next_obs.extend_from_slice(no),
            None => s.next_obs.extend_from_slice(&ep.obs[od..]),
        }
        s.act.extend_from_slice(ep.act);
        match ep.reward {
            Some(r) => s.reward.extend_from_slice(r),
            None => s.reward.extend(std::iter::repeat_n(0.0, n)),
        }
        s.episode.extend(std::iter::repeat_n(index, n));
        s.mode
            .extend(std::iter::repeat_n(label.unwrap_or(UNKNOWN_MODE), n));
        self.labels.push(label);
        self.ranges.push((start, start + n));
        Ok(())
    }

    fn label(&self, name: &str, label: Option<i64>) -> Result<Option<u32>, ImportError> {
        let Some(l) = label else { return Ok(None) };
        if l == -1 {
            return Ok(None);
        }
        let limit = self.opts.n_modes.unwrap_or(u32::MAX as usize - 1);
        match u32::try_from(l) {
            Ok(m) if (m as usize) < limit => Ok(Some(m)),
            _ => Err(self.invalid(format!(
                "{name}: label {l} is out of range: labels are 0..{limit} (-1: unknown){}",
                if self.opts.n_modes.is_some() {
                    " for the env's modes"
                } else {
                    ""
                }
            ))),
        }
    }

    /// Builds the dataset; `source` is the provenance without the options, which are
    /// added here.
    pub fn finish(self, mut source: DemoSource) -> Result<Demos, ImportError> {
        let opt_err = |what: String| ImportError::Options {
            path: self.path.clone(),
            what,
        };
        if self.ranges.is_empty() {
            return Err(opt_err("the source holds no episode".into()));
        }
        let labeled_modes: std::collections::BTreeSet<u32> =
            self.labels.iter().flatten().copied().collect();
        let k = match self.opts.n_modes {
            Some(k) => k,
            None => labeled_modes.iter().max().map_or(0, |&m| m as usize + 1),
        };
        if labeled_modes.len() < 2 {
            return Err(opt_err(format!(
                "{} mode(s) labeled ({labeled_modes:?}); at least two modes need labeled episodes",
                labeled_modes.len()
            )));
        }
        if let Some(m) = (0..k as u32).find(|m| !labeled_modes.contains(m)) {
            return Err(opt_err(format!(
                "mode {m} of 0..{k} has no labeled episode, so no label ratio can label it"
            )));
        }
        let r = self.opts.label_ratio;
        if !(r > 0.0 && r <= 1.0) {
            return Err(opt_err(format!("label ratio {r} must be in (0, 1]")));
        }
        let labeled = self.labeled_split(k);
        let meta = self.meta(k, &labeled, &mut source);
        Ok(Demos {
            meta,
            unlabeled: self.split,
            labeled,
        })
    }

    fn labeled_split(&self, k: usize) -> DemoSplit {
        let (od, ad) = self.opts.dims;
        let quota =
            ess_envs::demos::labeled_steps_per_mode(self.opts.label_ratio, self.split.len(), k);
        let mut rng = ChaCha8Rng::seed_from_u64(self.opts.seed);
        let mut labeled = DemoSplit::default();
        for mode in 0..k as u32 {
            let mut eps: Vec<usize> = (0..self.ranges.len())
                .filter(|&e| self.labels[e] == Some(mode))
                .collect();
            eps.shuffle(&mut rng);
            let mut part = DemoSplit::default();
            for e in eps {
                if part.len() >= quota {
                    break;
                }
                let (a, b) = self.ranges[e];
                let take = (b - a).min(quota - part.len());
                part.extend(&self.rows(a, a + take, od, ad));
            }
            if part.len() < quota {
                tracing::warn!(
                    mode,
                    have = part.len(),
                    quota,
                    "mode has fewer labeled steps than the label ratio asks for; all are used"
                );
            }
            labeled.extend(&part);
        }
        labeled
    }

    /// Rows `a..b` of the unlabeled split as one episode of index 0.
    fn rows(&self, a: usize, b: usize, od: usize, ad: usize) -> DemoSplit {
        let s = &self.split;
        DemoSplit {
            obs: s.obs[a * od..b * od].to_vec(),
            act: s.act[a * ad..b * ad].to_vec(),
            next_obs: s.next_obs[a * od..b * od].to_vec(),
            mode: s.mode[a..b].to_vec(),
            episode: vec![0; b - a],
            reward: s.reward[a..b].to_vec(),
        }
    }

    fn meta(&self, k: usize, labeled: &DemoSplit, source: &mut DemoSource) -> DemoMeta {
        let eps = self.split.episodes_per_mode(k);
        let steps = self.split.steps_per_mode(k);
        let known: Vec<usize> = steps.iter().copied().filter(|&s| s > 0).collect();
        let imbalance = match (known.iter().max(), known.iter().min()) {
            (Some(&hi), Some(&lo)) => hi as f64 / lo as f64,
            _ => 1.0,
        };
        let o = &self.opts;
        source.episodes = self.ranges.len();
        source
            .options
            .insert("label_ratio".into(), o.label_ratio.to_string());
        source.options.insert("seed".into(), o.seed.to_string());
        source.options.insert("env".into(), o.env.clone());
        source.options.extend(o.extra.clone());
        DemoMeta {
            format_version: ess_envs::demos::FORMAT_VERSION,
            env: o.env.clone(),
            obs_dim: o.dims.0,
            act_dim: o.dims.1,
            n_modes: k,
            episode_len: o.episode_len,
            label_ratio: o.label_ratio,
            imbalance_ratio: imbalance,
            majority_episodes: eps.iter().copied().max().unwrap_or(0),
            seed: o.seed,
            unlabeled_episodes_per_mode: eps,
            unlabeled_steps_per_mode: steps,
            labeled_steps_per_mode: labeled.steps_per_mode(k),
            generator: format!("ess {} (demos import)", env!("CARGO_PKG_VERSION")),
            source: Some(source.clone()),
        }
    }
}

/// Values per row of an array of `shape`: 0 for a scalar (no rows), 1 for a vector.
pub(crate) fn row_width(shape: &[usize]) -> usize {
    shape.get(1..).map_or(0, |s| s.iter().product())
}

/// SHA-256 of a file, hex, read in blocks.
pub fn sha256_file(path: &Path) -> Result<String, ImportError> {
    use std::io::Read;
    let err = |e: std::io::Error| ImportError::Read {
        path: path.to_owned(),
        reason: e.to_string(),
    };
    let mut f = std::fs::File::open(path).map_err(err)?;
    let mut h = sha2::Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f.read(&mut buf).map_err(err)?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(ess_proto::checksum::hex(h.finalize()))
}

/// A provenance record for `format` read from `path` (its hash of `data_file`).
pub fn source(format: &str, path: &Path, data_file: &Path) -> Result<DemoSource, ImportError> {
    Ok(DemoSource {
        format: format.into(),
        path: path.display().to_string(),
        sha256: sha256_file(data_file)?,
        episodes: 0,
        options: BTreeMap::new(),
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn row_width_is_zero_for_a_scalar_instead_of_panicking() {
        assert_eq!(super::row_width(&[]), 0);
        assert_eq!(super::row_width(&[7]), 1);
        assert_eq!(super::row_width(&[7, 8]), 8);
        assert_eq!(super::row_width(&[7, 2, 3]), 6);
    }
}
