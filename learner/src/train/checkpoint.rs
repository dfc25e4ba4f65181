//! Full training checkpoints: everything `ess train --resume DIR` needs to continue a
//! run bit-identically.
//!
//! One checkpoint is one directory `<out>/checkpoints/iter-NNNNNN/` (NNNNNN = iterations
//! done), written as `iter-NNNNNN.tmp/` and renamed when complete, so a run killed while
//! saving leaves the previous checkpoint as the latest:
//!
//! - `policy.safetensors`, `prior.safetensors`, `disc.safetensors`: the three variable
//!   stores (policy + value, p(c) logits, discriminator body and heads);
//! - `optim.safetensors`: Adam's moments of the three optimisers
//!   (`<opt>/<variable>/exp_avg`, `<opt>/<variable>/exp_avg_sq`);
//! - `state.json` ([`TrainState`]): counters, the learner's ChaCha8 stream, Adam step
//!   counts, the reward scaler, Q_c's running code marginal, the evaluation curve, the
//!   metrics row still waiting for its successor, and each actor's complete state
//!   (random stream, observation, latents, [`ess_envs::Env::state`]) between two steps.
//!
//! Every `.safetensors` file carries the checksums of its tensors
//! ([`crate::tensor_file`]), and `state.sha256` holds that of `state.json` (the format
//! of `sha256sum`, so `sha256sum -c state.sha256` checks it by hand); loading refuses
//! any mismatch naming the file (and tensor), so a flipped byte never resumes a
//! different run. The files stay byte-for-byte reproducible (one metadata entry each:
//! safetensors writes several in a random order). Format 2 (format 1 had no checksums).
//!
//! Floats in `state.json` round-trip exactly (serde_json's `float_roundtrip`). What is
//! not saved is recomputed identically from the run's `config.toml`: the dataset and its
//! normalisers, the behaviour classifier, and libtorch's random stream, which the
//! training loop re-seeds from the seed and the iteration at every iteration.

use crate::eval::report::CurvePoint;
use crate::train::optim::{Adam, AdamState};
use crate::train::{IterationLog, PhaseSeconds};
use anyhow::{Context, Result, bail};
use ess_actor::WorkerState;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use tch::{Tensor, nn};

/// Version of the checkpoint layout; a checkpoint of another version is refused.
pub const FORMAT: u32 = 2;
/// The file holding `state.json`'s SHA-256, as `sha256sum` writes it.
const STATE_SHA256: &str = "state.sha256";

/// The variable stores, in file order.
pub const STORES: [&str; 3] = ["policy", "prior", "disc"];

/// A ChaCha8 generator's position.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct RngState {
    /// Seed.
    pub seed: [u8; 32],
    /// Stream.
    pub stream: u64,
    /// Word position (decimal; a `u128`).
    pub word_pos: String,
}

impl RngState {
    /// Position of `rng`.
    pub fn of(rng: &ChaCha8Rng) -> Self {
        Self {
            seed: rng.get_seed(),
            stream: rng.get_stream(),
            word_pos: rng.get_word_pos().to_string(),
        }
    }

    /// A generator at this position.
    pub fn rng(&self) -> Result<ChaCha8Rng> {
        use rand::SeedableRng;
        let pos: u128 = self
            .word_pos
            .parse()
            .with_context(|| format!("rng word_pos `{}` is not a u128", self.word_pos))?;
        let mut r = ChaCha8Rng::from_seed(self.seed);
        r.set_stream(self.stream);
        r.set_word_pos(pos);
        Ok(r)
    }
}

/// One actor's [`WorkerState`] as saved.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SavedWorker {
    /// Its random stream.
    pub rng: RngState,
    /// Observation the next step acts on.
    pub obs: Vec<f32>,
    /// Current code.
    pub code: Vec<f32>,
    /// Gumbel noise of the code.
    pub gumbel: Vec<f32>,
    /// Current eps.
    pub eps: f32,
    /// Whether an episode is under way.
    pub in_episode: bool,
    /// The env's state vector.
    pub env: Vec<f64>,
}

impl From<&WorkerState> for SavedWorker {
    fn from(w: &WorkerState) -> Self {
        Self {
            rng: RngState {
                seed: w.rng_seed,
                stream: w.rng_stream,
                word_pos: w.rng_word_pos.to_string(),
            },
            obs: w.obs.clone(),
            code: w.code.clone(),
            gumbel: w.gumbel.clone(),
            eps: w.eps,
            in_episode: w.in_episode,
            env: w.env.clone(),
        }
    }
}

impl SavedWorker {
    /// Back to a [`WorkerState`].
    pub fn to_state(&self) -> Result<WorkerState> {
        Ok(WorkerState {
            rng_seed: self.rng.seed,
            rng_stream: self.rng.stream,
            rng_word_pos: self
                .rng
                .word_pos
                .parse()
                .with_context(|| format!("actor word_pos `{}`", self.rng.word_pos))?,
            obs: self.obs.clone(),
            code: self.code.clone(),
            gumbel: self.gumbel.clone(),
            eps: self.eps,
            in_episode: self.in_episode,
            env: self.env.clone(),
        })
    }
}

/// The reward scaler's statistics ([`crate::train::ppo::RewardScaler`]).
pub type ScalerState = crate::train::ppo::RewardScaler;

/// Everything of a run between two iterations that is not a tensor (`state.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrainState {
    /// [`FORMAT`].
    pub format: u32,
    /// Iterations done.
    pub iteration: usize,
    /// Environment steps so far.
    pub env_steps: usize,
    /// Training wall seconds so far.
    pub wall_s: f64,
    /// Summed per-phase seconds.
    pub phases: PhaseSeconds,
    /// Evaluation curve so far.
    pub curve: Vec<CurvePoint>,
    /// The metrics row of the last iteration, not yet in `metrics.csv`.
    pub pending: Option<IterationLog>,
    /// The learner's random stream (minibatches, D/Q batches).
    pub rng: RngState,
    /// Q_c's running estimate of the demos' code marginal.
    pub qc_marginal: Vec<f64>,
    /// Reward scaler.
    pub scaler: ScalerState,
    /// Adam step counts per optimiser and variable.
    pub adam_steps: BTreeMap<String, BTreeMap<String, i64>>,
    /// Each actor's state, in actor order; empty only when a snapshot failed (an actor
    /// lost during it), in which case a resumed run starts fresh episodes.
    pub actors: Vec<SavedWorker>,
    /// With `run.pipeline = "overlap"`: the weights the next iteration's rollout was
    /// collected under, as they travel to actor processes (the actors' states above
    /// are those from before it), so a resume collects it again; `None` in the
    /// synchronous pipeline.
    #[serde(default)]
    pub behaviour: Option<ess_proto::shm::WeightsMsg>,
}

/// Directory of the checkpoint after `iteration` iterations.
pub fn dir_for(root: &Path, iteration: usize) -> PathBuf {
    root.join(format!("iter-{iteration:06}"))
}

/// Writes a checkpoint into `root` (`checkpoints/`): `stores` and `opts` as named in
/// [`STORES`], `state` with the Adam step counts filled in. Returns its directory. A
/// failed save (a full disk) removes its partial `.tmp` directory, so the space goes
/// back and the previous checkpoint stays the latest.
pub fn save(
    root: &Path,
    stores: [&nn::VarStore; 3],
    opts: [&Adam; 3],
    state: &mut TrainState,
) -> Result<PathBuf> {
    let dir = dir_for(root, state.iteration);
    let tmp = dir.with_extension("tmp");
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).with_context(|| format!("removing {}", tmp.display()))?;
    }
    let written = write_files(&tmp, stores, opts, state);
    if let Err(e) = written {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e.context(format!("saving checkpoint {}", dir.display())));
    }
    if dir.exists() {
        std::fs::remove_dir_all(&dir).with_context(|| format!("replacing {}", dir.display()))?;
    }
    std::fs::rename(&tmp, &dir)
        .with_context(|| format!("renaming {} to {}", tmp.display(), dir.display()))?;
    Ok(dir)
}

/// The files of a checkpoint, written into `tmp`.
fn write_files(
    tmp: &Path,
    stores: [&nn::VarStore; 3],
    opts: [&Adam; 3],
    state: &mut TrainState,
) -> Result<()> {
    std::fs::create_dir_all(tmp).with_context(|| format!("creating {}", tmp.display()))?;
    for (name, vs) in STORES.iter().zip(stores) {
        crate::tensor_file::save_var_store(vs, &tmp.join(format!("{name}.safetensors")))?;
    }
    let mut tensors: Vec<(String, Tensor)> = Vec::new();
    state.adam_steps.clear();
    for (name, opt) in STORES.iter().zip(opts) {
        let mut steps = BTreeMap::new();
        for (var, (m, v, s)) in opt.state().params {
            tensors.push((format!("{name}/{var}/exp_avg"), m));
            tensors.push((format!("{name}/{var}/exp_avg_sq"), v));
            steps.insert(var, s);
        }
        state.adam_steps.insert(name.to_string(), steps);
    }
    crate::tensor_file::save(&tmp.join("optim.safetensors"), &tensors, Default::default())?;
    let state_json = serde_json::to_vec_pretty(state)?;
    let sum = format!(
        "{}  state.json\n",
        crate::tensor_file::sha256_hex(&state_json)
    );
    for (name, bytes) in [(STATE_SHA256, sum.as_bytes()), ("state.json", &state_json)] {
        let p = tmp.join(name);
        std::fs::write(&p, bytes).with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

/// The complete checkpoint with the most iterations under `root`, if any.
pub fn latest(root: &Path) -> Result<Option<PathBuf>> {
    if !root.is_dir() {
        return Ok(None);
    }
    let mut best: Option<(usize, PathBuf)> = None;
    for e in std::fs::read_dir(root).with_context(|| format!("listing {}", root.display()))? {
        let path = e?.path();
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
            continue;
        };
        let Some(Ok(it)) = name.strip_prefix("iter-").map(str::parse::<usize>) else {
            continue;
        };
        if path.join("state.json").is_file() && best.as_ref().is_none_or(|(b, _)| it > *b) {
            best = Some((it, path));
        }
    }
    Ok(best.map(|(_, p)| p))
}

/// Loads the checkpoint in `dir` into `stores` and `opts` (built for the same config)
/// and returns its [`TrainState`].
pub fn load(
    dir: &Path,
    stores: [&mut nn::VarStore; 3],
    opts: [&mut Adam; 3],
) -> Result<TrainState> {
    let p = dir.join("state.json");
    let text = std::fs::read(&p).with_context(|| format!("reading {}", p.display()))?;
    let format = serde_json::from_slice::<serde_json::Value>(&text)
        .ok()
        .and_then(|v| v.get("format").and_then(serde_json::Value::as_u64));
    if format.is_some_and(|f| f != u64::from(FORMAT)) {
        bail!(
            "{}: checkpoint format {} (this build reads format {FORMAT})",
            p.display(),
            format.unwrap_or_default()
        );
    }
    let sum_path = dir.join(STATE_SHA256);
    let sum = std::fs::read_to_string(&sum_path)
        .with_context(|| format!("reading {}", sum_path.display()))?;
    if sum.split_whitespace().next() != Some(&crate::tensor_file::sha256_hex(&text)) {
        return Err(crate::tensor_file::TensorFileError::Mismatch {
            path: p,
            sums: sum_path,
        }
        .into());
    }
    let state: TrainState =
        serde_json::from_slice(&text).with_context(|| format!("parsing {}", p.display()))?;
    if state.format != FORMAT {
        bail!(
            "{}: checkpoint format {} (this build reads format {FORMAT})",
            p.display(),
            state.format
        );
    }
    for (name, vs) in STORES.iter().zip(stores) {
        let p = dir.join(format!("{name}.safetensors"));
        crate::tensor_file::load_var_store(vs, &p)
            .with_context(|| format!("loading {} into this run's networks", p.display()))?;
    }
    let p = dir.join("optim.safetensors");
    let (mut tensors, _) = crate::tensor_file::load(&p).context("loading a checkpoint")?;
    for (name, opt) in STORES.iter().zip(opts) {
        let steps = state
            .adam_steps
            .get(*name)
            .with_context(|| format!("{}: no Adam steps of `{name}`", dir.display()))?;
        let mut st = AdamState::default();
        for (var, &s) in steps {
            let mut take = |what: &str| {
                let key = format!("{name}/{var}/{what}");
                tensors
                    .remove(&key)
                    .with_context(|| format!("{}: no tensor `{key}`", p.display()))
            };
            let m = take("exp_avg")?;
            let v = take("exp_avg_sq")?;
            st.params.insert(var.clone(), (m, v, s));
        }
        opt.set_state(&st)
            .with_context(|| format!("{}: optimizer `{name}`", p.display()))?;
    }
    Ok(state)
}

/// The actors' states for a checkpoint; none only when a snapshot failed (an actor lost
/// during it: logged, and `--resume` says so).
pub(super) fn actor_states(actors: &mut dyn ess_actor::RolloutSource) -> Vec<SavedWorker> {
    match actors.snapshot() {
        Ok(Some(states)) => states.iter().map(Into::into).collect(),
        Ok(None) => Vec::new(),
        Err(e) => {
            tracing::warn!(error = %e, "checkpoint without actor states");
            Vec::new()
        }
    }
}
