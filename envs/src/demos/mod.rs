//! Demonstration datasets: imbalanced unlabeled expert data plus a small balanced
//! labeled set (paper Sec. 4, "Multi-modal demonstrations preparation"), and their
//! safetensors file format.
//!
//! # Generation ([`generate_demos`])
//!
//! - **Unlabeled split.** Mode `k` contributes `max(1, round(majority_episodes * w_k))`
//!   whole expert episodes, `w = mode_weights(n_modes, imbalance_ratio)`. All episodes
//!   are shuffled together (episode order, seeded; each episode stays contiguous) and
//!   renumbered `0..`. Every step keeps its true mode in `mode`: only full-label
//!   baselines and analysis may read it, never semi-supervised training.
//! - **Labeled split.** Balanced: each mode gets
//!   `ceil(label_ratio * n_unlabeled_steps / n_modes)` steps from *fresh* expert episodes
//!   of that mode (whole episodes, the last one cut to length); `mode` is the label.
//!
//! Episode seeds come from one `ChaCha8Rng` seeded with `DemoSpec::seed`, so a spec
//! always yields the same dataset.
//!
//! # File format
//!
//! A standard safetensors file (`safetensors.numpy.load_file` opens it). For each split
//! `S` in `unlabeled`, `labeled` with `n` rows:
//!
//! | tensor         | dtype | shape          |
//! |----------------|-------|----------------|
//! | `S.obs`        | F32   | `[n, obs_dim]` |
//! | `S.act`        | F32   | `[n, act_dim]` |
//! | `S.next_obs`   | F32   | `[n, obs_dim]` |
//! | `S.mode`       | I32   | `[n]`          |
//! | `S.episode`    | I32   | `[n]`          |
//! | `S.reward`     | F32   | `[n]`          |
//!
//! `unlabeled.mode` is -1 where nobody knows the mode (an episode imported without a
//! label, [`UNKNOWN_MODE`] in memory); labels are always known.
//!
//! Header metadata: `format = "ess-demos"`, `format_version = "2"`, `meta` = the
//! [`DemoMeta`] as JSON, and `ess.sha256`, the checksums of every tensor and of the other
//! entries ([`ess_proto::checksum`]). [`Demos::load`] validates all of it and names the
//! offending tensor, row, field or value (and the file) in its error. Version 1 files
//! (written before the checksums) still load, unverified.

use std::collections::BTreeSet;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::env::EnvError;

/// Value of the `format` header key.
pub const FORMAT: &str = "ess-demos";
/// The `format_version` this build writes (sealed with checksums).
pub const FORMAT_VERSION: u32 = 2;
/// The version before checksums: still read, without them.
const UNSEALED_VERSION: u32 = 1;
/// The format as [`ess_proto::checksum::open`] checks it.
const FILE_FORMAT: ess_proto::checksum::Format = ess_proto::checksum::Format {
    name: FORMAT,
    current: FORMAT_VERSION,
    unsealed: UNSEALED_VERSION,
};
/// The in-memory mode of an unlabeled transition whose mode nobody knows (an imported
/// episode without a label); stored as `-1` in the file, only in the unlabeled split.
pub const UNKNOWN_MODE: u32 = u32::MAX;
/// Split names, in file order.
const SPLITS: [&str; 2] = ["unlabeled", "labeled"];

/// What dataset to generate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoSpec {
    /// Environment name (see [`crate::make_env`]).
    pub env: String,
    /// Number of behaviour modes.
    pub n_modes: usize,
    /// Labeled steps as a fraction of unlabeled steps, in `(0, 1]` (paper default for
    /// the 2D trajectory: 0.01).
    pub label_ratio: f64,
    /// Frequency ratio of the most to the least frequent mode, `>= 1` (paper: 100).
    pub imbalance_ratio: f64,
    /// Unlabeled episodes of each most frequent mode, `>= 1`.
    pub majority_episodes: usize,
    /// Seed of every random choice of the generation.
    pub seed: u64,
}

/// Transitions of one split, row-major.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DemoSplit {
    /// Observations, `[n][obs_dim]`.
    pub obs: Vec<f32>,
    /// Actions, `[n][act_dim]`.
    pub act: Vec<f32>,
    /// Next observations, `[n][obs_dim]`.
    pub next_obs: Vec<f32>,
    /// True behaviour mode (the label, in the labeled split), `[n]`.
    pub mode: Vec<u32>,
    /// Episode index within the split, `[n]`.
    pub episode: Vec<u32>,
    /// Evaluation reward of the episode's own mode, per step, `[n]`.
    pub reward: Vec<f32>,
}

impl DemoSplit {
    /// Number of transitions.
    pub fn len(&self) -> usize {
        self.mode.len()
    }

    /// True when the split holds no transition.
    pub fn is_empty(&self) -> bool {
        self.mode.is_empty()
    }

    /// Number of episodes: one past the largest episode index (0 when empty).
    pub fn n_episodes(&self) -> usize {
        self.episode.iter().max().map_or(0, |&e| e as usize + 1)
    }

    /// Appends `other`, offsetting its episode indices by [`Self::n_episodes`] so
    /// episodes stay distinct.
    pub fn extend(&mut self, other: &DemoSplit) {
        let offset = self.n_episodes() as u32;
        self.obs.extend_from_slice(&other.obs);
        self.act.extend_from_slice(&other.act);
        self.next_obs.extend_from_slice(&other.next_obs);
        self.mode.extend_from_slice(&other.mode);
        self.episode
            .extend(other.episode.iter().map(|&e| e + offset));
        self.reward.extend_from_slice(&other.reward);
    }

    /// Keeps the first `n` transitions (no-op when `n >= len`).
    fn truncate(&mut self, n: usize, obs_dim: usize, act_dim: usize) {
        if n >= self.len() {
            return;
        }
        self.obs.truncate(n * obs_dim);
        self.act.truncate(n * act_dim);
        self.next_obs.truncate(n * obs_dim);
        self.mode.truncate(n);
        self.episode.truncate(n);
        self.reward.truncate(n);
    }

    /// Steps per mode (`n_modes` entries; out-of-range modes are not counted).
    pub fn steps_per_mode(&self, n_modes: usize) -> Vec<usize> {
        let mut counts = vec![0; n_modes];
        for &m in &self.mode {
            if let Some(c) = counts.get_mut(m as usize) {
                *c += 1;
            }
        }
        counts
    }

    /// Distinct episodes per mode (an episode counts for the mode of its rows).
    pub fn episodes_per_mode(&self, n_modes: usize) -> Vec<usize> {
        let pairs: BTreeSet<(u32, u32)> = self
            .episode
            .iter()
            .zip(&self.mode)
            .map(|(&e, &m)| (e, m))
            .collect();
        let mut counts = vec![0; n_modes];
        for (_, m) in pairs {
            if let Some(c) = counts.get_mut(m as usize) {
                *c += 1;
            }
        }
        counts
    }
}

/// Description of a dataset, stored as JSON in the file header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoMeta {
    /// File format version ([`FORMAT_VERSION`]).
    pub format_version: u32,
    /// Environment name.
    pub env: String,
    /// Observation length.
    pub obs_dim: usize,
    /// Action length.
    pub act_dim: usize,
    /// Number of behaviour modes.
    pub n_modes: usize,
    /// Episode length of the env (`max_steps`).
    pub episode_len: usize,
    /// [`DemoSpec::label_ratio`].
    pub label_ratio: f64,
    /// [`DemoSpec::imbalance_ratio`].
    pub imbalance_ratio: f64,
    /// [`DemoSpec::majority_episodes`].
    pub majority_episodes: usize,
    /// [`DemoSpec::seed`].
    pub seed: u64,
    /// Unlabeled episodes of each mode.
    pub unlabeled_episodes_per_mode: Vec<usize>,
    /// Unlabeled steps of each mode.
    pub unlabeled_steps_per_mode: Vec<usize>,
    /// Labeled steps of each mode.
    pub labeled_steps_per_mode: Vec<usize>,
    /// Program that wrote the file, `"ess <version>"`.
    pub generator: String,
    /// Where imported demonstrations came from (`ess demos import`); absent for
    /// generated ones.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<DemoSource>,
}

/// Provenance of an imported dataset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoSource {
    /// Source format: `minari` or `npz`.
    pub format: String,
    /// The source path as given.
    pub path: String,
    /// SHA-256 of the source's data file, hex.
    pub sha256: String,
    /// Episodes read from the source.
    pub episodes: usize,
    /// The import's options (label ratio, label field or file, seed, ...).
    pub options: std::collections::BTreeMap<String, String>,
}

/// A demonstration dataset.
#[derive(Debug, Clone, PartialEq)]
pub struct Demos {
    /// Description and counts.
    pub meta: DemoMeta,
    /// Imbalanced unlabeled demonstrations (with true modes for analysis only).
    pub unlabeled: DemoSplit,
    /// Balanced labeled demonstrations.
    pub labeled: DemoSplit,
}

/// Errors of dataset generation, saving and loading. Load errors name the file.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    /// A [`DemoSpec`] field is invalid.
    #[error("invalid demo spec: {field} = {value}: {reason}")]
    BadSpec {
        /// Field name.
        field: &'static str,
        /// Its value, formatted.
        value: String,
        /// Why it is rejected.
        reason: &'static str,
    },
    /// The environment failed.
    #[error(transparent)]
    Env(#[from] EnvError),
    /// Reading or writing the file failed.
    #[error("{path}: I/O error: {error}")]
    Io {
        /// File involved.
        path: PathBuf,
        /// Underlying error (in the message, not repeated as a source).
        error: std::io::Error,
    },
    /// The safetensors container could not be built.
    #[error("{path}: cannot serialize safetensors: {reason}")]
    Serialize {
        /// File being written.
        path: PathBuf,
        /// Underlying error, formatted.
        reason: String,
    },
    /// The file's layout, `format`, `format_version` or checksums are wrong
    /// (truncated, corrupt, another format or version, a flipped byte).
    #[error("{path}: {error}")]
    Header {
        /// File read.
        path: PathBuf,
        /// What is wrong, naming the key or tensor.
        error: ess_proto::checksum::OpenError,
    },
    /// The `format_version` inside `meta` is not one this build reads.
    #[error(
        "{path}: unsupported meta format_version {found}; this build reads versions {UNSEALED_VERSION} and {FORMAT_VERSION}"
    )]
    UnsupportedVersion {
        /// File read.
        path: PathBuf,
        /// Version found.
        found: u32,
    },
    /// The `meta` header key is not valid [`DemoMeta`] JSON.
    #[error("{path}: header meta is not valid DemoMeta JSON: {error}")]
    BadMeta {
        /// File read.
        path: PathBuf,
        /// JSON error, formatted.
        error: String,
    },
    /// A `meta` field is inconsistent in itself.
    #[error("{path}: meta.{field} = {value}: {reason}")]
    BadMetaField {
        /// File read.
        path: PathBuf,
        /// Field name.
        field: &'static str,
        /// Its value, formatted.
        value: String,
        /// Why it is rejected.
        reason: String,
    },
    /// A required tensor is missing.
    #[error("{path}: tensor {tensor:?} is missing")]
    MissingTensor {
        /// File read.
        path: PathBuf,
        /// Tensor name.
        tensor: String,
    },
    /// A tensor has the wrong dtype.
    #[error("{path}: tensor {tensor:?} has dtype {got}, expected {expected}")]
    WrongDtype {
        /// File read.
        path: PathBuf,
        /// Tensor name.
        tensor: String,
        /// Expected dtype.
        expected: String,
        /// Dtype found.
        got: String,
    },
    /// A tensor has the wrong shape.
    #[error("{path}: tensor {tensor:?} has shape {got:?}, expected {expected}")]
    WrongShape {
        /// File read.
        path: PathBuf,
        /// Tensor name.
        tensor: String,
        /// Expected shape, formatted (`n` for any row count).
        expected: String,
        /// Shape found.
        got: Vec<usize>,
    },
    /// Tensors of one split disagree on the row count.
    #[error("{path}: tensor {tensor:?} has {rows} rows but {split}.mode has {expected_rows}")]
    RowCountMismatch {
        /// File read.
        path: PathBuf,
        /// Split name.
        split: &'static str,
        /// Tensor name.
        tensor: String,
        /// Its row count.
        rows: usize,
        /// Row count of `{split}.mode`.
        expected_rows: usize,
    },
    /// A mode/label value is negative or `>= n_modes`.
    #[error("{path}: tensor {tensor:?} row {row}: mode {value} is out of range 0..{n_modes}")]
    ModeOutOfRange {
        /// File read.
        path: PathBuf,
        /// Tensor name.
        tensor: String,
        /// Row index.
        row: usize,
        /// Value found.
        value: i64,
        /// Number of modes.
        n_modes: usize,
    },
    /// An episode index is negative.
    #[error("{path}: tensor {tensor:?} row {row}: episode index {value} is negative")]
    NegativeEpisode {
        /// File read.
        path: PathBuf,
        /// Tensor name.
        tensor: String,
        /// Row index.
        row: usize,
        /// Value found.
        value: i64,
    },
    /// A float is NaN or infinite.
    #[error("{path}: tensor {tensor:?} row {row} holds a non-finite value {value}")]
    NonFinite {
        /// File read.
        path: PathBuf,
        /// Tensor name.
        tensor: String,
        /// Row index.
        row: usize,
        /// Value found.
        value: f32,
    },
    /// A count in meta disagrees with the arrays.
    #[error("{path}: meta.{field} = {in_meta:?} but the arrays give {in_arrays:?}")]
    CountMismatch {
        /// File read.
        path: PathBuf,
        /// Meta field name.
        field: &'static str,
        /// Value in meta.
        in_meta: Vec<usize>,
        /// Value computed from the arrays.
        in_arrays: Vec<usize>,
    },
}

mod file;
mod generate;

pub use generate::{expert_episode, generate_demos, labeled_steps_per_mode, mode_weights};

#[cfg(test)]
mod tests {
    use super::file::{RawTensor, header, split_tensors};
    use super::*;
    use crate::registry::make_env;
    use proptest::prelude::*;
    use safetensors::tensor::{Dtype, TensorView};
    use std::borrow::Cow;
    use std::collections::HashMap;
    use std::path::Path;

    fn spec(majority: usize, label_ratio: f64) -> DemoSpec {
        DemoSpec {
            env: "traj2d".into(),
            n_modes: 4,
            label_ratio,
            imbalance_ratio: 100.0,
            majority_episodes: majority,
            seed: 42,
        }
    }

    fn small_demos() -> Demos {
        generate_demos(&spec(4, 0.1)).expect("generate")
    }

    #[test]
    fn unknown_modes_round_trip_in_the_unlabeled_split_only() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("u.safetensors");
        let mut d = small_demos();
        // Episode 0 of the unlabeled split loses its mode, as an unlabeled import would.
        let lost: Vec<usize> = (0..d.unlabeled.len())
            .filter(|&i| d.unlabeled.episode[i] == 0)
            .collect();
        for &i in &lost {
            d.unlabeled.mode[i] = UNKNOWN_MODE;
        }
        d.meta.unlabeled_episodes_per_mode = d.unlabeled.episodes_per_mode(4);
        d.meta.unlabeled_steps_per_mode = d.unlabeled.steps_per_mode(4);
        d.meta.source = Some(DemoSource {
            format: "npz".into(),
            path: "x.npz".into(),
            sha256: "0".repeat(64),
            episodes: 3,
            options: [("label_ratio".to_string(), "0.1".to_string())].into(),
        });
        d.save(&path).expect("save");
        let back = Demos::load(&path).expect("load");
        assert_eq!(back, d);
        assert_eq!(back.unlabeled.mode[lost[0]], UNKNOWN_MODE);
        // A label of -1 is refused: labels are always known.
        d.labeled.mode[0] = UNKNOWN_MODE;
        d.meta.labeled_steps_per_mode = d.labeled.steps_per_mode(4);
        d.save(&path).expect("save");
        let err = Demos::load(&path).expect_err("unknown label");
        assert!(
            err.to_string().contains("labeled.mode") && err.to_string().contains("mode -1"),
            "{err}"
        );
    }

    fn close(a: &[f64], b: &[f64]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12)
    }

    #[test]
    fn mode_weights_follow_the_group_rule() {
        assert!(close(&mode_weights(4, 100.0), &[1.0, 1.0, 0.01, 0.01]));
        assert!(close(
            &mode_weights(6, 100.0),
            &[1.0, 1.0, 0.1, 0.1, 0.01, 0.01]
        ));
        assert!(close(&mode_weights(3, 100.0), &[1.0, 0.1, 0.01]));
        assert!(close(&mode_weights(2, 100.0), &[1.0, 0.01]));
        assert!(close(&mode_weights(1, 100.0), &[1.0]));
        assert!(close(&mode_weights(4, 1.0), &[1.0; 4]));
    }

    #[test]
    fn imbalanced_demos_have_the_expected_episode_counts() {
        let demos = generate_demos(&spec(200, 0.01)).expect("generate");
        assert_eq!(demos.meta.unlabeled_episodes_per_mode, vec![200, 200, 2, 2]);
        assert_eq!(demos.unlabeled.episodes_per_mode(4), vec![200, 200, 2, 2]);
        assert_eq!(
            demos.meta.unlabeled_steps_per_mode,
            vec![20000, 20000, 200, 200]
        );
        assert_eq!(demos.unlabeled.n_episodes(), 404);
    }

    #[test]
    fn labeled_steps_per_mode_is_the_ceiling_of_the_ratio_share() {
        assert_eq!(labeled_steps_per_mode(0.01, 40400, 4), 101);
        assert_eq!(labeled_steps_per_mode(0.01, 40401, 4), 102);
        assert_eq!(labeled_steps_per_mode(1.0, 10, 4), 3);
        let demos = generate_demos(&spec(3, 0.05)).expect("generate");
        // 3 + 3 + 1 + 1 episodes of 100 steps = 800 steps; 0.05 * 800 / 4 = 10.
        assert_eq!(demos.unlabeled.len(), 800);
        assert_eq!(demos.meta.labeled_steps_per_mode, vec![10; 4]);
        assert_eq!(demos.labeled.len(), 40);
        // Cut from one episode per mode.
        assert_eq!(demos.labeled.n_episodes(), 4);
        let demos = generate_demos(&spec(3, 1.0)).expect("generate");
        // 200 steps per mode = two whole episodes per mode.
        assert_eq!(demos.meta.labeled_steps_per_mode, vec![200; 4]);
        assert_eq!(demos.labeled.episodes_per_mode(4), vec![2; 4]);
    }

    #[test]
    fn unlabeled_episodes_are_shuffled_and_contiguous() {
        let demos = generate_demos(&spec(10, 0.01)).expect("generate");
        let u = &demos.unlabeled;
        let first_modes: Vec<u32> = (0..u.n_episodes())
            .map(|e| u.mode[u.episode.iter().position(|&x| x as usize == e).expect("ep")])
            .collect();
        let mut sorted = first_modes.clone();
        sorted.sort_unstable();
        assert_ne!(first_modes, sorted, "episodes should be mixed");
        assert!(
            u.episode
                .windows(2)
                .all(|w| w[1] == w[0] || w[1] == w[0] + 1)
        );
        // next_obs of a step is obs of the following step within an episode.
        for i in 0..u.len() - 1 {
            if u.episode[i] == u.episode[i + 1] {
                assert_eq!(
                    u.next_obs[i * 10..(i + 1) * 10],
                    u.obs[(i + 1) * 10..(i + 2) * 10]
                );
            }
        }
    }

    #[test]
    fn generation_is_deterministic_given_the_seed() {
        let a = small_demos();
        let b = small_demos();
        assert_eq!(a, b);
        let c = generate_demos(&DemoSpec {
            seed: 43,
            ..spec(4, 0.1)
        })
        .expect("generate");
        assert_ne!(a.unlabeled, c.unlabeled);
    }

    #[test]
    fn expert_episode_rewards_are_those_of_its_own_mode() {
        let mut env = make_env("traj2d", 4).expect("env");
        for mode in 0..4 {
            let ep = expert_episode(env.as_mut(), mode, 9).expect("episode");
            assert_eq!(ep.len(), 100);
            let mean: f32 = ep.reward.iter().sum::<f32>() / ep.len() as f32;
            assert!(mean > -0.1 && mean <= 0.0, "mode {mode}: {mean}");
        }
        let err = expert_episode(env.as_mut(), 4, 9).unwrap_err();
        assert!(matches!(err, EnvError::ModeOutOfRange { mode: 4, .. }));
    }

    #[test]
    fn invalid_specs_are_rejected_naming_the_field() {
        let cases = [
            (
                DemoSpec {
                    label_ratio: 0.0,
                    ..spec(2, 0.1)
                },
                "label_ratio",
            ),
            (
                DemoSpec {
                    label_ratio: 1.5,
                    ..spec(2, 0.1)
                },
                "label_ratio",
            ),
            (
                DemoSpec {
                    imbalance_ratio: 0.5,
                    ..spec(2, 0.1)
                },
                "imbalance_ratio",
            ),
            (
                DemoSpec {
                    imbalance_ratio: f64::INFINITY,
                    ..spec(2, 0.1)
                },
                "imbalance_ratio",
            ),
            (
                DemoSpec {
                    n_modes: 1,
                    ..spec(2, 0.1)
                },
                "n_modes",
            ),
            (
                DemoSpec {
                    majority_episodes: 0,
                    ..spec(2, 0.1)
                },
                "majority_episodes",
            ),
        ];
        for (s, field) in cases {
            let err = generate_demos(&s).expect_err(field);
            assert!(
                matches!(err, DemoError::BadSpec { field: f, .. } if f == field),
                "{field}: {err}"
            );
            assert!(err.to_string().contains(field), "{err}");
        }
        let err = generate_demos(&DemoSpec {
            env: "nope".into(),
            ..spec(2, 0.1)
        })
        .unwrap_err();
        assert!(err.to_string().contains("nope"), "{err}");
    }

    #[test]
    fn saved_demos_load_back_equal() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("demos.safetensors");
        let demos = small_demos();
        demos.save(&path).expect("save");
        let back = Demos::load(&path).expect("load");
        assert_eq!(back, demos);
        // No temporary file is left behind.
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .expect("read_dir")
            .map(|e| e.expect("entry").file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
    }

    #[test]
    fn saving_over_an_existing_file_replaces_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("d.safetensors");
        std::fs::write(&path, b"old").expect("write");
        let demos = small_demos();
        demos.save(&path).expect("save");
        assert_eq!(Demos::load(&path).expect("load"), demos);
    }

    #[test]
    fn saving_into_a_missing_directory_is_an_io_error_naming_the_path() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("missing").join("d.safetensors");
        let err = small_demos().save(&path).unwrap_err();
        assert!(matches!(err, DemoError::Io { .. }), "{err}");
        assert!(err.to_string().contains("missing"), "{err}");
    }

    // ---- corrupt files -------------------------------------------------------------

    /// A writable description of a demos file, to corrupt one piece at a time.
    struct RawFile {
        tensors: Vec<RawTensor<'static>>,
        header: HashMap<String, String>,
    }

    impl RawFile {
        fn of(demos: &Demos) -> Self {
            let mut tensors = split_tensors("unlabeled", &demos.unlabeled, &demos.meta);
            tensors.extend(split_tensors("labeled", &demos.labeled, &demos.meta));
            let tensors = tensors
                .into_iter()
                .map(|(n, d, s, b)| (n, d, s, Cow::Owned(b.into_owned())))
                .collect();
            let meta = serde_json::to_string(&demos.meta).expect("json");
            Self {
                tensors,
                header: header(meta),
            }
        }

        fn tensor(&mut self, name: &str) -> &mut RawTensor<'static> {
            self.tensors
                .iter_mut()
                .find(|t| t.0 == name)
                .expect("tensor exists")
        }

        fn bytes(&self) -> Vec<u8> {
            let views: Vec<(String, TensorView<'_>)> = self
                .tensors
                .iter()
                .map(|(n, d, s, b)| (n.clone(), TensorView::new(*d, s.clone(), b).expect("view")))
                .collect();
            // Sealed as saved files are, so each test reaches the check it is about.
            let mut header = self.header.clone();
            ess_proto::checksum::seal(&mut header, views.iter().map(|(n, v)| (n.as_str(), v)));
            safetensors::serialize(views, Some(header)).expect("serialize")
        }

        fn load_err(&self) -> String {
            load_bytes_err(&self.bytes())
        }
    }

    const PATH: &str = "/data/corrupt.safetensors";

    fn load_bytes_err(bytes: &[u8]) -> String {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("corrupt.safetensors");
        std::fs::write(&path, bytes).expect("write");
        let err = Demos::load(&path).expect_err("corrupt file must not load");
        let msg = err.to_string();
        assert!(
            msg.contains(&path.display().to_string()),
            "no path in: {msg}"
        );
        // The in-memory parser names the path it is given too.
        let msg2 = Demos::from_bytes(bytes, Path::new(PATH))
            .expect_err("corrupt")
            .to_string();
        assert!(msg2.contains(PATH), "{msg2}");
        msg
    }

    fn assert_names(msg: &str, parts: &[&str]) {
        for p in parts {
            assert!(msg.contains(p), "{p:?} not in: {msg}");
        }
    }

    #[test]
    fn the_unmodified_raw_file_loads() {
        let demos = small_demos();
        let bytes = RawFile::of(&demos).bytes();
        assert_eq!(
            Demos::from_bytes(&bytes, Path::new(PATH)).expect("load"),
            demos
        );
    }

    #[test]
    fn a_truncated_file_is_rejected_as_not_safetensors() {
        let bytes = RawFile::of(&small_demos()).bytes();
        for cut in [3, 20, bytes.len() / 2, bytes.len() - 1] {
            let msg = load_bytes_err(&bytes[..cut]);
            assert_names(&msg, &["not a safetensors file"]);
        }
    }

    #[test]
    fn garbage_bytes_are_rejected_as_not_safetensors() {
        let msg = load_bytes_err(b"this is certainly not a safetensors file at all");
        assert_names(&msg, &["not a safetensors file"]);
        let msg = load_bytes_err(b"");
        assert_names(&msg, &["not a safetensors file"]);
    }

    #[test]
    fn a_missing_or_wrong_format_string_is_rejected() {
        let mut raw = RawFile::of(&small_demos());
        raw.header.insert("format".into(), "not-demos".into());
        assert_names(&raw.load_err(), &["format", "not-demos", FORMAT]);
        raw.header.remove("format");
        assert_names(&raw.load_err(), &["\"format\"", "missing"]);
    }

    #[test]
    fn an_unsupported_format_version_is_rejected() {
        let mut raw = RawFile::of(&small_demos());
        raw.header.insert("format_version".into(), "7".into());
        assert_names(&raw.load_err(), &["format_version", "\"7\""]);
    }

    #[test]
    fn bad_meta_json_is_rejected_naming_the_json_error() {
        let mut raw = RawFile::of(&small_demos());
        raw.header.insert("meta".into(), "{\"env\": 3".into());
        assert_names(&raw.load_err(), &["meta", "JSON", "line 1"]);
        let mut raw = RawFile::of(&small_demos());
        raw.header.insert("meta".into(), "{}".into());
        assert_names(&raw.load_err(), &["missing field"]);
    }

    #[test]
    fn a_missing_tensor_is_rejected_naming_it() {
        let mut raw = RawFile::of(&small_demos());
        raw.tensors.retain(|t| t.0 != "labeled.reward");
        assert_names(&raw.load_err(), &["labeled.reward", "missing"]);
    }

    #[test]
    fn a_wrong_dtype_is_rejected_naming_tensor_expected_and_found() {
        let mut raw = RawFile::of(&small_demos());
        let t = raw.tensor("unlabeled.mode");
        t.1 = Dtype::F32;
        assert_names(&raw.load_err(), &["unlabeled.mode", "I32", "F32"]);
    }

    #[test]
    fn a_wrong_shape_is_rejected_naming_tensor_expected_and_found() {
        let mut raw = RawFile::of(&small_demos());
        let t = raw.tensor("unlabeled.obs");
        let n = t.2[0];
        t.2 = vec![n * 2, 5];
        assert_names(
            &raw.load_err(),
            &["unlabeled.obs", "[n, 10]", &format!("[{}, 5]", n * 2)],
        );
    }

    #[test]
    fn row_counts_that_disagree_within_a_split_are_rejected() {
        let mut raw = RawFile::of(&small_demos());
        let t = raw.tensor("labeled.act");
        let n = t.2[0];
        t.2 = vec![n - 1, 1];
        t.3.to_mut().truncate((n - 1) * 4);
        assert_names(
            &raw.load_err(),
            &["labeled.act", &format!("{} rows", n - 1), &n.to_string()],
        );
    }

    #[test]
    fn a_label_out_of_range_is_rejected_naming_tensor_row_and_value() {
        for (value, shown) in [(4i32, "mode 4"), (-1, "mode -1")] {
            let mut raw = RawFile::of(&small_demos());
            let t = raw.tensor("labeled.mode");
            t.3.to_mut()[12..16].copy_from_slice(&value.to_le_bytes());
            assert_names(&raw.load_err(), &["labeled.mode", "row 3", shown, "0..4"]);
        }
    }

    #[test]
    fn a_negative_episode_index_is_rejected() {
        let mut raw = RawFile::of(&small_demos());
        let t = raw.tensor("unlabeled.episode");
        t.3.to_mut()[0..4].copy_from_slice(&(-2i32).to_le_bytes());
        assert_names(&raw.load_err(), &["unlabeled.episode", "row 0", "-2"]);
    }

    #[test]
    fn a_nan_value_is_rejected_naming_tensor_and_row() {
        let mut raw = RawFile::of(&small_demos());
        let t = raw.tensor("unlabeled.next_obs");
        // Row 7, column 3 of [n, 10].
        let at = (7 * 10 + 3) * 4;
        t.3.to_mut()[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        assert_names(&raw.load_err(), &["unlabeled.next_obs", "row 7", "NaN"]);
        let mut raw = RawFile::of(&small_demos());
        let t = raw.tensor("labeled.reward");
        t.3.to_mut()[8..12].copy_from_slice(&f32::INFINITY.to_le_bytes());
        assert_names(&raw.load_err(), &["labeled.reward", "row 2", "inf"]);
    }

    #[test]
    fn meta_counts_that_disagree_with_the_arrays_are_rejected() {
        let mut demos = small_demos();
        demos.meta.unlabeled_steps_per_mode[0] += 1;
        let msg = RawFile::of(&demos).load_err();
        assert_names(&msg, &["unlabeled_steps_per_mode"]);
        let mut demos = small_demos();
        demos.meta.unlabeled_episodes_per_mode[3] = 9;
        assert_names(
            &RawFile::of(&demos).load_err(),
            &["unlabeled_episodes_per_mode", "9"],
        );
        let mut demos = small_demos();
        demos.meta.labeled_steps_per_mode.pop();
        assert_names(
            &RawFile::of(&demos).load_err(),
            &["labeled_steps_per_mode", "3 entries", "n_modes = 4"],
        );
    }

    // ---- property: round trip of small random datasets ------------------------------

    fn arb_split(
        n_modes: usize,
        obs_dim: usize,
        act_dim: usize,
    ) -> impl Strategy<Value = DemoSplit> {
        (0usize..12).prop_flat_map(move |n| {
            let f = -1e6f32..1e6f32;
            (
                proptest::collection::vec(f.clone(), n * obs_dim),
                proptest::collection::vec(f.clone(), n * act_dim),
                proptest::collection::vec(f.clone(), n * obs_dim),
                proptest::collection::vec(0..n_modes as u32, n),
                proptest::collection::vec(0u32..5, n),
                proptest::collection::vec(f, n),
            )
                .prop_map(|(obs, act, next_obs, mode, episode, reward)| DemoSplit {
                    obs,
                    act,
                    next_obs,
                    mode,
                    episode,
                    reward,
                })
        })
    }

    fn arb_demos() -> impl Strategy<Value = Demos> {
        (
            2usize..5,
            1usize..4,
            1usize..3,
            any::<u64>(),
            0.001f64..1.0,
            1.0f64..1000.0,
        )
            .prop_flat_map(|(n_modes, obs_dim, act_dim, seed, label_ratio, imb)| {
                (
                    arb_split(n_modes, obs_dim, act_dim),
                    arb_split(n_modes, obs_dim, act_dim),
                )
                    .prop_map(move |(unlabeled, labeled)| {
                        let meta = DemoMeta {
                            format_version: FORMAT_VERSION,
                            env: "traj2d".into(),
                            obs_dim,
                            act_dim,
                            n_modes,
                            episode_len: 100,
                            label_ratio,
                            imbalance_ratio: imb,
                            majority_episodes: 3,
                            seed,
                            unlabeled_episodes_per_mode: unlabeled.episodes_per_mode(n_modes),
                            unlabeled_steps_per_mode: unlabeled.steps_per_mode(n_modes),
                            source: None,
                            labeled_steps_per_mode: labeled.steps_per_mode(n_modes),
                            generator: "ess test".into(),
                        };
                        Demos {
                            meta,
                            unlabeled,
                            labeled,
                        }
                    })
            })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        #[test]
        fn any_small_dataset_survives_a_save_load_round_trip(demos in arb_demos()) {
            let dir = tempfile::tempdir().expect("tempdir");
            let path = dir.path().join("p.safetensors");
            demos.save(&path).expect("save");
            let back = Demos::load(&path).expect("load");
            prop_assert_eq!(back, demos);
        }

        #[test]
        fn extend_concatenates_and_keeps_episodes_distinct(
            a in arb_split(3, 2, 1),
            b in arb_split(3, 2, 1),
        ) {
            let mut c = a.clone();
            c.extend(&b);
            prop_assert_eq!(c.len(), a.len() + b.len());
            prop_assert_eq!(c.obs.len(), c.len() * 2);
            prop_assert_eq!(&c.mode[a.len()..], &b.mode[..]);
            prop_assert_eq!(c.n_episodes(), if b.is_empty() { a.n_episodes() } else { a.n_episodes() + b.n_episodes() });
        }
    }
}
