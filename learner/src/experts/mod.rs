//! Expert training and evaluation (paper Sec. 4, "Multi-modal demonstrations
//! preparation": "we first pre-train K expert policies, each corresponding to K
//! different goals").
//!
//! `ess experts train --env E --mode k` trains mode `k`'s expert with the same PPO as
//! the imitation learner ([`crate::train::ppo`]), on the env's *task* reward of that mode
//! ([`ess_envs::Env::task_rewards`]) instead of a discriminator. The policy has no
//! latent: its eps and code inputs are held at zero (the file records them as
//! `extra_inputs`). Observations are normalised with running statistics of every
//! observation seen, frozen into the weights of each rollout and saved with the
//! expert. Rewards are scaled by the running return standard deviation.
//!
//! Outputs: the expert file ([`ess_envs::ExpertPolicy`]), written atomically after
//! every iteration, and beside it `<file>.state.safetensors` (policy + value
//! variables) and `<file>.csv` (one row per iteration), so `--resume` continues a run.
//! `--init-from FILE` starts a new expert from another expert of the same env (its
//! policy, value and normaliser, and its step count), e.g. a runner from a balancer.

pub mod sac;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use ess_actor::{LatentSpec, RolloutSource, ThreadedActors, Worker};
use ess_envs::{Env, ExpertMeta, ExpertPolicy, make_plain_env};
use ess_proto::Chunk;
use ess_proto::config::{LatentPrior, PpoConfig};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tch::{Tensor, nn};

use crate::train::nets::{export_policy, tensor_2d, tensor_to_vec};
use crate::train::ppo::{PpoBatch, PpoLearner, RewardScaler, column, rollout_gae};

/// What to train.
#[derive(Debug, Clone)]
pub struct ExpertTrainConfig {
    /// Environment name.
    pub env: String,
    /// Mode count of the env.
    pub n_modes: usize,
    /// Mode whose task reward is maximised.
    pub mode: usize,
    /// Total env steps (including those of a resumed run).
    pub steps: u64,
    /// Env steps per PPO iteration.
    pub rollout_steps: usize,
    /// Rollout workers.
    pub actors: usize,
    /// Threads of this process or `ess-actor` processes (`run.transport`).
    pub transport: ess_proto::config::ActorTransport,
    /// Seconds without a heartbeat before an actor process is restarted.
    pub actor_timeout_s: f64,
    /// libtorch intra-op threads.
    pub torch_threads: usize,
    /// Seed.
    pub seed: u64,
    /// PPO settings.
    pub ppo: PpoConfig,
    /// Expert file to write.
    pub out: PathBuf,
    /// Continue from `out` and its state file instead of starting afresh.
    pub resume: bool,
    /// Start from this expert file (any mode of the same env) and its state file: its
    /// policy, value, normaliser and step count, as `resume` would take them from `out`,
    /// but training `mode` into `out` with a fresh CSV. Exclusive with `resume`.
    pub init_from: Option<PathBuf>,
}

/// One iteration's report.
#[derive(Debug, Clone, Default)]
pub struct ExpertIteration {
    /// Iteration index (1-based, continuing across resumes).
    pub iteration: usize,
    /// Env steps so far.
    pub env_steps: u64,
    /// Mean task return of the episodes that ended in this iteration (`None` if none).
    pub mean_return: Option<f64>,
    /// Mean length of those episodes.
    pub mean_length: Option<f64>,
    /// Seconds this iteration took.
    pub seconds: f64,
    /// Policy entropy after the update.
    pub entropy: f64,
}

impl ExpertIteration {
    /// This report as a row of the expert's CSV (the columns `open_csv` writes).
    pub(crate) fn write_csv_row(&self, w: &mut impl Write) -> std::io::Result<()> {
        writeln!(
            w,
            "{},{},{},{},{:.4},{:.4}",
            self.iteration,
            self.env_steps,
            self.mean_return
                .map(|v| format!("{v:.4}"))
                .unwrap_or_default(),
            self.mean_length
                .map(|v| format!("{v:.1}"))
                .unwrap_or_default(),
            self.seconds,
            self.entropy
        )
    }
}

/// Running per-dimension mean and variance (Welford, merged per batch).
#[derive(Debug, Clone)]
pub(crate) struct RunningStats {
    pub(crate) count: f64,
    pub(crate) mean: Vec<f64>,
    pub(crate) m2: Vec<f64>,
}

impl RunningStats {
    pub(crate) fn new(d: usize) -> Self {
        Self {
            count: 0.0,
            mean: vec![0.0; d],
            m2: vec![0.0; d],
        }
    }

    pub(crate) fn update(&mut self, rows: &[f32]) {
        let d = self.mean.len();
        for row in rows.chunks_exact(d) {
            self.count += 1.0;
            for (j, &x) in row.iter().enumerate() {
                let delta = x as f64 - self.mean[j];
                self.mean[j] += delta / self.count;
                self.m2[j] += delta * (x as f64 - self.mean[j]);
            }
        }
    }

    pub(crate) fn mean_std(&self) -> (Vec<f32>, Vec<f32>) {
        let std = self
            .m2
            .iter()
            .map(|m| {
                if self.count < 2.0 {
                    1.0
                } else {
                    ((m / self.count).sqrt() as f32).max(1e-3)
                }
            })
            .collect();
        (self.mean.iter().map(|&m| m as f32).collect(), std)
    }
}

/// `expert`'s path with `suffix` appended (`mode1.safetensors` -> `mode1.safetensors.csv`).
fn beside(expert: &Path, suffix: &str) -> PathBuf {
    let mut s = expert.as_os_str().to_owned();
    s.push(suffix);
    PathBuf::from(s)
}

/// The state file beside an expert file.
pub fn state_path(expert: &Path) -> PathBuf {
    beside(expert, ".state.safetensors")
}

/// The per-iteration CSV beside an expert file.
pub fn csv_path(expert: &Path) -> PathBuf {
    beside(expert, ".csv")
}

/// The SAC replay buffer beside an expert file.
pub fn replay_path(expert: &Path) -> PathBuf {
    beside(expert, ".replay.safetensors")
}

/// Mean return and mean length of `(return, length)` episodes; `None` for none.
pub(crate) fn episode_means(episodes: &[(f64, usize)]) -> (Option<f64>, Option<f64>) {
    let n = episodes.len() as f64;
    let mean = |f: fn(&(f64, usize)) -> f64| {
        (!episodes.is_empty()).then(|| episodes.iter().map(f).sum::<f64>() / n)
    };
    (mean(|e| e.0), mean(|e| e.1 as f64))
}

/// Episode returns ending in `chunks`, continuing each stream's open episode in `open`.
fn finished_episodes(chunks: &[Chunk], open: &mut Vec<(f64, usize)>) -> Vec<(f64, usize)> {
    if open.len() < chunks.len() {
        open.resize(chunks.len(), (0.0, 0));
    }
    let mut done = Vec::new();
    for (c, acc) in chunks.iter().zip(open.iter_mut()) {
        for i in 0..c.len() {
            acc.0 += c.env_reward[i] as f64;
            acc.1 += 1;
            if c.terminated[i] || c.truncated[i] {
                done.push(*acc);
                *acc = (0.0, 0);
            }
        }
    }
    done
}

/// Loads the start of a resumed run (`cfg.resume`: `cfg.out` and its state) or a warm
/// start (`cfg.init_from`) into `vs` and `stats`; returns the env steps already taken
/// (0 for a fresh expert).
fn load_start(
    cfg: &ExpertTrainConfig,
    spec: &ess_envs::EnvSpec,
    vs: &mut nn::VarStore,
    stats: &mut RunningStats,
) -> Result<u64> {
    let source = match &cfg.init_from {
        Some(p) => Some(p.as_path()),
        None => cfg.resume.then_some(cfg.out.as_path()),
    };
    if let Some(src) = source {
        let old = ExpertPolicy::load(src)?;
        // Resuming continues the same mode; a warm start may come from any mode.
        let mode = if cfg.resume { cfg.mode } else { old.meta.mode };
        old.check_fits(spec, mode, src)?;
        let state = state_path(src);
        crate::tensor_file::load_var_store(vs, &state)
            .with_context(|| format!("loading training state {}", state.display()))?;
        let (m, s) = old.obs_stats();
        // Resume the normaliser as if from `trained_steps` observations.
        stats.count = old.meta.trained_steps as f64;
        stats.mean = m.iter().map(|&x| x as f64).collect();
        stats.m2 = s
            .iter()
            .map(|&x| (x as f64).powi(2) * stats.count)
            .collect();
        return Ok(old.meta.trained_steps);
    }
    Ok(0)
}

/// The rollout source of an expert run: actor threads or processes, each stepping the
/// plain env under mode `cfg.mode`'s task reward.
fn expert_actors(cfg: &ExpertTrainConfig, seeds: Vec<u64>) -> Result<Box<dyn RolloutSource>> {
    // One code slot, always zero: no latent (prior None keeps it zero).
    let latent = LatentSpec {
        prior: LatentPrior::None,
        n_codes: 1,
        tau: 1.0,
        use_eps: false,
    };
    Ok(match cfg.transport {
        ess_proto::config::ActorTransport::Threads => {
            let workers: Vec<Worker> = seeds
                .iter()
                .map(|&seed| -> Result<Worker> {
                    let env = make_plain_env(&cfg.env, cfg.n_modes)?;
                    Ok(Worker::new(env, seed, 1).with_task_reward(cfg.mode)?)
                })
                .collect::<Result<_>>()?;
            Box::new(ThreadedActors::new(workers, latent))
        }
        ess_proto::config::ActorTransport::Processes => Box::new(crate::actors::ShmActors::new(
            crate::actors::ShmActorsConfig {
                run_id: crate::actors::new_run_id(),
                binary: crate::actors::actor_binary()?,
                env: cfg.env.clone(),
                n_modes: cfg.n_modes,
                latent,
                max_steps: cfg.rollout_steps.div_ceil(cfg.actors),
                seeds,
                heartbeat_timeout: std::time::Duration::from_secs_f64(cfg.actor_timeout_s),
                startup_timeout: std::time::Duration::from_secs(30),
                plain_env: true,
                task_mode: Some(cfg.mode),
            },
        )?),
    })
}

/// The PPO batch of one rollout: observations normalised with `(obs_mean, obs_std)`,
/// GAE on the task reward with `scaler`, no code and no eps.
fn ppo_batch(
    cfg: &ExpertTrainConfig,
    ppo: &PpoLearner,
    scaler: &mut RewardScaler,
    chunks: &[Chunk],
    all: &Chunk,
    (obs_mean, obs_std): (&[f32], &[f32]),
) -> PpoBatch {
    let (od, ad) = (all.obs_dim, all.act_dim);
    let norm = |x: &[f32]| {
        let mut v = x.to_vec();
        crate::eval::classifier::normalize_rows(&mut v, obs_mean, obs_std);
        tensor_2d(&v, od)
    };
    let obs_n = norm(&all.obs);
    let next_n = norm(&all.next_obs);
    let n = all.len() as i64;
    let zeros = Tensor::zeros([n, 1], (tch::Kind::Float, tch::Device::Cpu));
    let eps_col = column(&all.eps);
    let (values, next_values) = tch::no_grad(|| {
        let vin = Tensor::cat(&[&obs_n, &eps_col, &zeros], 1);
        let nin = Tensor::cat(&[&next_n, &eps_col, &zeros], 1);
        (
            tensor_to_vec(&ppo.values(&vin)),
            tensor_to_vec(&ppo.values(&nin)),
        )
    });
    let (adv, ret) = rollout_gae(
        &cfg.ppo,
        scaler,
        chunks,
        &all.env_reward,
        &values,
        &next_values,
    );
    PpoBatch {
        obs: obs_n,
        eps: eps_col,
        code: zeros.shallow_clone(),
        gumbel: zeros,
        pre_tanh: tensor_2d(&all.pre_tanh, ad),
        old_logp: Tensor::from_slice(&all.logp),
        adv: Tensor::from_slice(&adv),
        returns: Tensor::from_slice(&ret),
    }
}

/// Trains one expert; `progress` sees every iteration. Stops early (saving) when
/// `shutdown` is set. Returns the saved expert.
pub fn train_expert(
    cfg: &ExpertTrainConfig,
    progress: &mut dyn FnMut(&ExpertIteration),
    shutdown: &AtomicBool,
) -> Result<ExpertPolicy> {
    let spec = checked_spec(cfg)?;
    tch::set_num_threads(cfg.torch_threads.max(1) as i32);
    tch::manual_seed(cfg.seed as i64);
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0xE4BE57);
    let (od, ad) = (spec.obs_dim, spec.act_dim);
    // The policy reads `[obs, eps, code]`, eps and code held at zero.
    let mut vs = nn::VarStore::new(tch::Device::Cpu);
    let prior_vs = nn::VarStore::new(tch::Device::Cpu);
    let mut ppo = PpoLearner::new(
        &vs,
        &prior_vs,
        od + 2,
        ad,
        1,
        &cfg.ppo,
        LatentPrior::None,
        1.0,
    )?;
    let mut stats = RunningStats::new(od);
    let mut env_steps = load_start(cfg, &spec, &mut vs, &mut stats)?;
    let first_iteration = (env_steps / cfg.rollout_steps as u64) as usize + 1;
    let seeds: Vec<u64> = (0..cfg.actors)
        .map(|i| {
            cfg.seed
                .wrapping_mul(7_919)
                .wrapping_add(env_steps)
                .wrapping_add(i as u64)
        })
        .collect();
    let mut actors = expert_actors(cfg, seeds)?;
    let mut csv = open_csv(cfg)?;
    let mut scaler = RewardScaler::default();
    let mut open = Vec::new();
    let mut recent: Vec<f64> = Vec::new();
    let mut it = first_iteration;
    let mut expert = None;
    while env_steps < cfg.steps {
        if shutdown.load(Ordering::Relaxed) {
            break;
        }
        let t0 = Instant::now();
        let (obs_mean, obs_std) = stats.mean_std();
        let weights = Arc::new(export_policy(
            &ppo.policy,
            &ppo.prior_logits,
            &obs_mean,
            &obs_std,
            it as u64,
        )?);
        let chunks = actors.collect(weights, cfg.rollout_steps)?;
        let mut all = Chunk::with_capacity(od, ad, 1, cfg.rollout_steps);
        for c in &chunks {
            all.extend(c);
        }
        env_steps += all.len() as u64;
        let episodes = finished_episodes(&chunks, &mut open);
        recent.extend(episodes.iter().map(|e| e.0));
        let keep = recent.len().saturating_sub(100);
        recent.drain(..keep);
        let batch = ppo_batch(cfg, &ppo, &mut scaler, &chunks, &all, (&obs_mean, &obs_std));
        let st = ppo.update(&batch, &mut rng);
        // The normaliser learns from this rollout only after the update used it.
        stats.update(&all.obs);
        let (mean_return, mean_length) = episode_means(&episodes);
        let report = ExpertIteration {
            iteration: it,
            env_steps,
            mean_return,
            mean_length,
            seconds: t0.elapsed().as_secs_f64(),
            entropy: st.entropy,
        };
        report.write_csv_row(&mut csv)?;
        progress(&report);
        it += 1;
        // Save every 10 iterations and at the end (the state file is what resumes).
        if it.is_multiple_of(10) || env_steps >= cfg.steps || shutdown.load(Ordering::Relaxed) {
            expert = Some(save(cfg, &spec, (&ppo, &vs), &stats, env_steps, &recent)?);
            csv.flush()?;
        }
    }
    csv.flush()?;
    match expert {
        Some(e) => Ok(e),
        None => save(cfg, &spec, (&ppo, &vs), &stats, env_steps, &recent),
    }
}

/// The spec of the env `cfg` trains on, after the checks that need no training:
/// the mode exists, at least one actor and step, `resume` without `init_from`.
fn checked_spec(cfg: &ExpertTrainConfig) -> Result<ess_envs::EnvSpec> {
    let spec = make_plain_env(&cfg.env, cfg.n_modes)?.spec().clone();
    if cfg.mode >= spec.n_modes {
        bail!(ess_envs::EnvError::ModeOutOfRange {
            mode: cfg.mode,
            n_modes: spec.n_modes
        });
    }
    if cfg.rollout_steps == 0 || cfg.actors == 0 {
        bail!("rollout_steps and actors must be at least 1");
    }
    if cfg.resume && cfg.init_from.is_some() {
        bail!("resume and init_from exclude each other");
    }
    Ok(spec)
}

/// Creates `cfg.out`'s directory and opens its CSV: appending when resuming, else
/// fresh with the header.
pub(crate) fn open_csv(cfg: &ExpertTrainConfig) -> Result<std::io::BufWriter<std::fs::File>> {
    if let Some(dir) = cfg.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let csv_file = csv_path(&cfg.out);
    let mut csv = std::io::BufWriter::new(
        std::fs::OpenOptions::new()
            .create(true)
            .append(cfg.resume)
            .write(true)
            .truncate(!cfg.resume)
            .open(&csv_file)
            .with_context(|| format!("opening {}", csv_file.display()))?,
    );
    if !cfg.resume {
        writeln!(
            csv,
            "iteration,env_steps,mean_return,mean_length,seconds,entropy"
        )?;
    }
    Ok(csv)
}

/// The iteration number of the last row of the CSV at `path` (none if it has no data
/// row or cannot be read): a resumed run numbers its rows on from it.
pub(crate) fn last_csv_iteration(path: &Path) -> Option<usize> {
    let text = std::fs::read_to_string(path).ok()?;
    let last = text.lines().rev().find(|l| !l.trim().is_empty())?;
    last.split(',').next()?.trim().parse().ok()
}

/// The meta of an expert trained by `cfg`: mean return over `recent` episodes,
/// `learner` appended to the generator (e.g. " (sac)").
pub(crate) fn expert_meta(
    cfg: &ExpertTrainConfig,
    spec: &ess_envs::EnvSpec,
    sizes: Vec<usize>,
    extra_inputs: usize,
    env_steps: u64,
    recent: &[f64],
    learner: &str,
) -> ExpertMeta {
    ExpertMeta {
        env: spec.name.clone(),
        mode: cfg.mode,
        n_modes: spec.n_modes,
        obs_dim: spec.obs_dim,
        act_dim: spec.act_dim,
        sizes,
        extra_inputs,
        trained_steps: env_steps,
        mean_return: if recent.is_empty() {
            0.0
        } else {
            recent.iter().sum::<f64>() / recent.len() as f64
        },
        generator: format!("ess {}{learner}", env!("CARGO_PKG_VERSION")),
    }
}

/// Saves the expert file and the run's state file (the networks: what resumes).
fn save(
    cfg: &ExpertTrainConfig,
    spec: &ess_envs::EnvSpec,
    (ppo, vs): (&PpoLearner, &nn::VarStore),
    stats: &RunningStats,
    env_steps: u64,
    recent: &[f64],
) -> Result<ExpertPolicy> {
    let (obs_mean, obs_std) = stats.mean_std();
    let w = export_policy(&ppo.policy, &ppo.prior_logits, &obs_mean, &obs_std, 0)?;
    let meta = expert_meta(
        cfg,
        spec,
        w.mean.layout().sizes.clone(),
        2,
        env_steps,
        recent,
        "",
    );
    let e = ExpertPolicy::new(meta, w.mean.params().to_vec(), w.log_std, obs_mean, obs_std)
        .map_err(|r| anyhow::anyhow!("exported expert is inconsistent: {r}"))?;
    e.save(&cfg.out)?;
    crate::tensor_file::save_var_store(vs, &state_path(&cfg.out))?;
    Ok(e)
}

/// One row of `ess experts eval`.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ExpertEvalRow {
    /// Mode.
    pub mode: usize,
    /// Mean task return of the mode's expert (stochastic, as it generates demos).
    pub expert_return: f64,
    /// Mean task return of the mode under uniformly random actions.
    pub random_return: f64,
    /// Mean episode length of the expert.
    pub expert_length: f64,
    /// Mean forward velocity of the expert over its steps (locomotion envs).
    pub forward_velocity: Option<f64>,
    /// Mean forward velocity under random actions.
    pub random_forward_velocity: Option<f64>,
}

/// Evaluates `experts[k]` (one per mode) on `env` against uniformly random actions,
/// `episodes` episodes each, scoring mode `k`'s task reward.
pub fn eval_experts(
    env: &mut dyn Env,
    experts: &[ExpertPolicy],
    episodes: usize,
    seed: u64,
) -> Result<Vec<ExpertEvalRow>> {
    use rand::Rng;
    let spec = env.spec().clone();
    let mut rows = Vec::new();
    for (mode, e) in experts.iter().enumerate() {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ mode as u64);
        let mut buf = e.scratch();
        let mut run = |policy: Option<&ExpertPolicy>,
                       rng: &mut ChaCha8Rng|
         -> Result<(f64, f64, Option<f64>)> {
            let (mut ret, mut len, mut vel, mut nvel) = (0.0, 0.0, 0.0, 0usize);
            let mut obs = vec![0.0; spec.obs_dim];
            let mut act = vec![0.0; spec.act_dim];
            let mut r = vec![0.0; spec.n_modes];
            for _ in 0..episodes {
                env.reset(rng.random(), &mut obs)?;
                loop {
                    match policy {
                        Some(p) => p.act(&obs, 1.0, rng, &mut buf, &mut act),
                        None => act
                            .iter_mut()
                            .for_each(|a| *a = rng.random_range(-1.0..1.0)),
                    }
                    let out = env.step(&act, &mut obs)?;
                    env.task_rewards(&mut r);
                    ret += r[mode] as f64;
                    len += 1.0;
                    if let Some(v) = env.forward_velocity() {
                        vel += v;
                        nvel += 1;
                    }
                    if out.done() {
                        break;
                    }
                }
            }
            let n = episodes.max(1) as f64;
            Ok((ret / n, len / n, (nvel > 0).then(|| vel / nvel as f64)))
        };
        let (er, el, ev) = run(Some(e), &mut rng)?;
        let (rr, _, rv) = run(None, &mut rng)?;
        rows.push(ExpertEvalRow {
            mode,
            expert_return: er,
            random_return: rr,
            expert_length: el,
            forward_velocity: ev,
            random_forward_velocity: rv,
        });
    }
    Ok(rows)
}
