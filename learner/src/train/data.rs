//! The data the stages read: the demonstrations as D's input tensors, the observation
//! normaliser, the rollout as tensors, and the minibatch draws.

use super::records::EncoderAccuracy;
use crate::train::nets::{Discriminator, obs_columns, tensor_2d};
use anyhow::{Result, bail};
use ess_actor::{PolicyWeights, RolloutSource};
use ess_envs::{DemoSpec, Demos, generate_demos};
use ess_proto::{CheckedConfig, Chunk};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use std::path::PathBuf;
use std::sync::Arc;
use tch::Tensor;

/// A configuration that the env it names cannot take; the CLI exits 2 on it.
#[derive(Debug, thiserror::Error)]
pub enum TrainInputError {
    /// A `[remote]` file (CA, certificate, key) that cannot serve.
    #[error("{0}")]
    RemoteTls(String),
    /// `disc.obs_prefix` longer than the observation.
    #[error("disc.obs_prefix = {prefix} exceeds env `{env}`'s observation length {obs_dim}")]
    DiscObsPrefix {
        /// The configured prefix.
        prefix: usize,
        /// The env's name.
        env: String,
        /// Its observation length.
        obs_dim: usize,
    },
    /// A task file has no experts to generate demonstrations with.
    #[error(
        "env `{env}` is a task file: it has no experts to generate demonstrations with; set \
         demos.path to a file written by `ess demos import`"
    )]
    TaskNeedsDemos {
        /// The env's name.
        env: String,
    },
    /// The demonstrations file does not fit the configured env.
    #[error("{0}")]
    DemosMismatch(String),
}

/// The dataset a configuration asks for.
pub fn demo_spec(cfg: &CheckedConfig) -> DemoSpec {
    DemoSpec {
        env: cfg.env.name.clone(),
        n_modes: cfg.env.n_modes,
        label_ratio: cfg.demos.label_ratio,
        imbalance_ratio: cfg.demos.imbalance_ratio,
        majority_episodes: cfg.demos.majority_episodes,
        seed: cfg.demos.seed,
    }
}

/// Loads the configured dataset or generates it.
pub fn load_or_generate_demos(cfg: &CheckedConfig) -> Result<Demos> {
    if cfg.demos.path.is_empty() {
        Ok(generate_demos(&demo_spec(cfg))?)
    } else {
        let path = PathBuf::from(&cfg.demos.path);
        let d = Demos::load(&path)?;
        if d.meta.env != cfg.env.name || d.meta.n_modes != cfg.env.n_modes {
            return Err(TrainInputError::DemosMismatch(format!(
                "{}: dataset is for env `{}` with {} modes, config asks env.name = `{}`, env.n_modes = {}",
                path.display(),
                d.meta.env,
                d.meta.n_modes,
                cfg.env.name,
                cfg.env.n_modes
            ))
            .into());
        }
        Ok(d)
    }
}

/// Widths the stages need: observation, action, codes, and the observation and action
/// entries D reads (`disc.obs_prefix`, `disc.actions`).
#[derive(Debug, Clone, Copy)]
pub struct Dims {
    /// Observation width.
    pub obs: usize,
    /// Action width.
    pub act: usize,
    /// Number of codes K.
    pub codes: usize,
    /// Observation entries D, Q_c and Q_eps read.
    pub disc_cols: usize,
    /// Action entries they read: `act`, or 0 with `disc.actions = false`.
    pub disc_act: usize,
}

impl Dims {
    /// The widths of a run of `cfg` on an env with `obs`/`act` entries; the error names
    /// `disc.obs_prefix` when it is longer than the observation.
    pub fn new(
        cfg: &CheckedConfig,
        env: &str,
        obs: usize,
        act: usize,
    ) -> Result<Self, TrainInputError> {
        let disc_cols = obs_columns(cfg.disc.obs_prefix, obs).ok_or_else(|| {
            TrainInputError::DiscObsPrefix {
                prefix: cfg.disc.obs_prefix,
                env: env.to_string(),
                obs_dim: obs,
            }
        })?;
        Ok(Self {
            obs,
            act,
            codes: cfg.env.n_modes,
            disc_cols,
            disc_act: if cfg.disc.actions { act } else { 0 },
        })
    }

    /// Width of one D input row, `[norm(s)[..disc_cols], a[..disc_act]]`.
    pub fn disc_inp(&self) -> usize {
        self.disc_cols + self.disc_act
    }
}

/// The observation normaliser (the unlabeled demonstrations' mean and std).
pub struct ObsNorm {
    /// Per-entry mean.
    pub mean: Vec<f32>,
    /// Per-entry std.
    pub std: Vec<f32>,
}

impl ObsNorm {
    /// `[n, obs_dim]` observations normalised.
    pub fn apply(&self, obs: &[f32]) -> Tensor {
        let mut v = obs.to_vec();
        crate::eval::classifier::normalize_rows(&mut v, &self.mean, &self.std);
        tensor_2d(&v, self.mean.len())
    }
}

/// Discriminator inputs `[norm(s)[..disc_cols], a]` from normalised observations and
/// actions, `a` left out when D reads states only (`disc_act = 0`, `disc.actions`).
pub fn disc_inputs(obs_n: &Tensor, act: &[f32], d: Dims) -> Tensor {
    let s = obs_n.narrow(1, 0, d.disc_cols as i64);
    if d.disc_act == 0 {
        return s.contiguous();
    }
    Tensor::cat(&[&s, &tensor_2d(act, d.act)], 1)
}

fn modes(m: &[u32]) -> Tensor {
    Tensor::from_slice(&m.iter().map(|&m| i64::from(m)).collect::<Vec<_>>())
}

/// Expert data as D's input tensors.
pub struct ExpertData {
    /// `[n, disc_inp]` normalised unlabeled inputs.
    pub unlabeled: Tensor,
    /// `[n]` true modes (only for the full-label baseline and the encoder accuracy).
    pub unlabeled_mode: Tensor,
    /// `[m, disc_inp]` labeled inputs.
    pub labeled: Tensor,
    /// `[m]` labels.
    pub labels: Tensor,
}

impl ExpertData {
    /// D's view of `demos`.
    pub fn new(demos: &Demos, norm: &ObsNorm, d: Dims) -> Self {
        let x = |obs: &[f32], act: &[f32]| disc_inputs(&norm.apply(obs), act, d);
        Self {
            unlabeled: x(&demos.unlabeled.obs, &demos.unlabeled.act),
            unlabeled_mode: modes(&demos.unlabeled.mode),
            labeled: x(&demos.labeled.obs, &demos.labeled.act),
            labels: modes(&demos.labeled.mode),
        }
    }

    /// The share of each of `k` modes among the unlabeled demonstrations (their true
    /// modes, which only a generated dataset knows); empty when none is known.
    pub fn mode_frequencies(&self, k: usize) -> Vec<f64> {
        let modes: Vec<i64> = Vec::try_from(&self.unlabeled_mode).unwrap_or_default();
        let mut counts = vec![0u64; k];
        for m in modes {
            if let Some(c) = usize::try_from(m).ok().and_then(|m| counts.get_mut(m)) {
                *c += 1;
            }
        }
        let total: u64 = counts.iter().sum();
        if total == 0 {
            return Vec::new();
        }
        counts.iter().map(|&c| c as f64 / total as f64).collect()
    }

    /// [`EncoderAccuracy`] of `disc`'s Q_c head on the unlabeled demonstrations, in
    /// batches so memory stays flat.
    pub fn encoder_accuracy(&self, disc: &Discriminator, k: usize) -> EncoderAccuracy {
        let n = self.unlabeled.size()[0];
        let mut hits = vec![0u64; k];
        let mut counts = vec![0u64; k];
        let _guard = tch::no_grad_guard();
        let mut start = 0;
        while start < n {
            let len = (n - start).min(65_536);
            let pred = disc
                .forward(&self.unlabeled.narrow(0, start, len))
                .qc_logits
                .argmax(-1, false);
            let p: Vec<i64> = Vec::try_from(&pred).unwrap_or_default();
            let t: Vec<i64> =
                Vec::try_from(&self.unlabeled_mode.narrow(0, start, len)).unwrap_or_default();
            for (&p, &t) in p.iter().zip(&t) {
                if let Ok(t) = usize::try_from(t)
                    && t < k
                {
                    counts[t] += 1;
                    hits[t] += u64::from(p == t as i64);
                }
            }
            start += len;
        }
        EncoderAccuracy::from_counts(&hits, &counts)
    }
}

/// One iteration's rollout: the actors' chunks and the tensors the stages read.
pub struct Rollout {
    /// One chunk per actor, in actor order.
    pub chunks: Vec<Chunk>,
    /// The chunks concatenated.
    pub all: Chunk,
    /// `[n, obs]` normalised observations.
    pub obs_n: Tensor,
    /// `[n, disc_inp]` D's inputs.
    pub disc_x: Tensor,
    /// `[n, K]` soft codes.
    pub code: Tensor,
    /// `[n]` eps.
    pub eps: Tensor,
}

impl Rollout {
    /// The tensors of `chunks` (already checked for their policy version).
    pub fn new(chunks: Vec<Chunk>, norm: &ObsNorm, d: Dims) -> Self {
        let cap = chunks.iter().map(Chunk::len).sum();
        let mut all = Chunk::with_capacity(d.obs, d.act, d.codes, cap);
        for c in &chunks {
            all.extend(c);
        }
        let obs_n = norm.apply(&all.obs);
        Self {
            disc_x: disc_inputs(&obs_n, &all.act, d),
            code: tensor_2d(&all.code, d.codes),
            eps: Tensor::from_slice(&all.eps),
            obs_n,
            chunks,
            all,
        }
    }

    /// Transitions.
    pub fn len(&self) -> usize {
        self.all.len()
    }

    /// Whether it holds no transition.
    pub fn is_empty(&self) -> bool {
        self.all.len() == 0
    }
}

/// Draws generated transitions so that code `j` (its episode's `argmax c`) makes up a
/// share `target[j]` of the batch (`method.disc_code_reweight`).
pub struct CodeReweight {
    /// Cumulative sampling weights, one per transition.
    cumulative: Vec<f64>,
}

impl CodeReweight {
    /// Weights for soft codes `code` (`[n * k]`) toward the marginal `target`.
    pub fn new(code: &[f32], k: usize, target: &[f64]) -> Self {
        let codes: Vec<usize> = code
            .chunks_exact(k.max(1))
            .map(|c| {
                c.iter()
                    .enumerate()
                    .fold((0, f32::MIN), |b, (i, &v)| if v > b.1 { (i, v) } else { b })
                    .0
            })
            .collect();
        let mut count = vec![0usize; k];
        for &j in &codes {
            count[j] += 1;
        }
        let mut acc = 0.0;
        let cumulative = codes
            .iter()
            .map(|&j| {
                acc += target.get(j).copied().unwrap_or(0.0).max(1e-6) / count[j] as f64;
                acc
            })
            .collect();
        Self { cumulative }
    }

    /// `batch` indices drawn with the weights.
    pub fn sample(&self, rng: &mut ChaCha8Rng, batch: i64) -> Vec<i64> {
        let total = self.cumulative.last().copied().unwrap_or(0.0);
        (0..batch)
            .map(|_| {
                let u = rng.random_range(0.0..total.max(f64::MIN_POSITIVE));
                self.cumulative
                    .partition_point(|&c| c <= u)
                    .min(self.cumulative.len().saturating_sub(1)) as i64
            })
            .collect()
    }
}

/// `batch` indices drawn uniformly from `0..n`.
pub fn sample_idx(rng: &mut ChaCha8Rng, n: i64, batch: i64) -> Vec<i64> {
    (0..batch).map(|_| rng.random_range(0..n.max(1))).collect()
}

/// `steps` transitions from `actors` under `weights`, every chunk checked to come
/// from them.
pub fn gather(
    actors: &mut dyn RolloutSource,
    weights: Arc<PolicyWeights>,
    steps: usize,
) -> Result<Vec<Chunk>> {
    let version = weights.version;
    let chunks = actors.collect(weights, steps)?;
    if let Some(c) = chunks.iter().find(|c| c.policy_version != version) {
        bail!(
            "chunk of policy version {} where version {version} was asked for",
            c.policy_version
        );
    }
    Ok(chunks)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn humanoid(set: &[&str]) -> CheckedConfig {
        let mut b = ess_proto::config::ConfigBuilder::new();
        b.set("env.name=\"humanoid\"").expect("env");
        for kv in set {
            b.set(kv).expect("set");
        }
        b.build().expect("config")
    }

    #[test]
    fn a_state_only_d_reads_the_observation_columns_alone() {
        let norm = ObsNorm {
            mean: vec![0.0; 3],
            std: vec![1.0; 3],
        };
        let (obs, act) = ([1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0], [0.5f32, -0.5]);
        let obs_n = norm.apply(&obs);
        let with = Dims::new(&humanoid(&["disc.obs_prefix=2"]), "h", 3, 1).expect("dims");
        let x = disc_inputs(&obs_n, &act, with);
        assert_eq!(x.size(), [2, with.disc_inp() as i64]);
        assert_eq!(
            Vec::<f32>::try_from(x.view([-1])).expect("f32"),
            [1.0, 2.0, 0.5, 4.0, 5.0, -0.5]
        );
        let cfg = humanoid(&["disc.obs_prefix=2", "disc.actions=false"]);
        let without = Dims::new(&cfg, "h", 3, 1).expect("dims");
        assert_eq!((without.disc_act, without.disc_inp()), (0, 2));
        let x = disc_inputs(&obs_n, &act, without);
        assert_eq!(
            Vec::<f32>::try_from(x.view([-1])).expect("f32"),
            [1.0, 2.0, 4.0, 5.0]
        );
        let err = Dims::new(&humanoid(&["disc.obs_prefix=4"]), "h", 3, 1).expect_err("too long");
        assert_eq!(
            err.to_string(),
            "disc.obs_prefix = 4 exceeds env `h`'s observation length 3"
        );
    }

    #[test]
    fn code_reweighting_draws_each_code_at_its_target_share() {
        // 80 transitions of code 0, 20 of code 1 (soft codes, argmax decides); the
        // target marginal is the reverse.
        let mut code = Vec::new();
        for i in 0..100 {
            code.extend_from_slice(if i < 80 { &[0.9f32, 0.1] } else { &[0.2, 0.8] });
        }
        let d = CodeReweight::new(&code, 2, &[0.2, 0.8]);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let idx = d.sample(&mut rng, 20_000);
        assert!(idx.iter().all(|&i| (0..100).contains(&i)));
        let share1 = idx.iter().filter(|&&i| i >= 80).count() as f64 / idx.len() as f64;
        assert!((share1 - 0.8).abs() < 0.02, "{share1}");
        // Within a code, transitions are drawn evenly.
        let first = idx.iter().filter(|&&i| i == 0).count() as f64 / idx.len() as f64;
        assert!((first - 0.2 / 80.0).abs() < 0.002, "{first}");
    }

    #[test]
    fn encoder_accuracy_counts_each_mode_on_its_own() {
        let acc = EncoderAccuracy::from_counts(&[9, 1, 0], &[10, 1, 0]);
        assert!((acc.overall - 10.0 / 11.0).abs() < 1e-12);
        assert!((acc.balanced - (0.9 + 1.0 + 0.0) / 3.0).abs() < 1e-12);
        assert_eq!(acc.per_mode, vec![0.9, 1.0, 0.0]);
    }
}
