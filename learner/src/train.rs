//! The training loop (Algorithm 1), one for all seven methods.
//!
//! Each iteration: the actors roll out `run.rollout_steps` transitions under the current
//! policy and latents `(c, eps)`; the discriminator body with heads D, Q_c, Q_eps takes
//! `disc.steps` steps on the weighted objective terms ([`crate::objective`]); the policy
//! reward is computed with the updated heads; PPO updates policy, value and p(c).
//! Periodic evaluations follow the paper's protocol ([`crate::eval`]).

use crate::actors::{ShmActors, ShmActorsConfig, actor_binary, new_run_id};
use crate::eval::{EvalResult, build_reference, evaluate};
use crate::nets::{Discriminator, export_policy, tensor_2d, tensor_to_vec};
use crate::objective::{
    contrastive::nt_xent,
    disc_bce::disc_bce,
    grad_penalty::r1_penalty,
    qc_ce::{hard_cross_entropy, soft_cross_entropy},
    qeps::qeps_mae,
    reward::{RewardWeights, disc_term, policy_reward},
    rim::rim,
};
use crate::ppo::{PpoBatch, PpoLearner, PpoStats, column, rollout_gae};
use anyhow::{Context, Result, bail};
use ess_actor::{LatentSpec, LocalEval, PolicyWeights, RolloutSource, ThreadedActors, Worker};
use ess_envs::{DemoSpec, Demos, generate_demos, make_env};
use ess_proto::config::ActorTransport;
use ess_proto::config::LatentPrior;
use ess_proto::{CheckedConfig, Chunk};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;
use tch::{Kind, Tensor, nn};

/// What a caller sees of progress (the CLI draws a bar or prints lines).
pub trait Progress {
    /// Called after each iteration.
    fn iteration(&mut self, it: &IterationLog);
    /// Free-form status message (set-up phases).
    fn message(&mut self, msg: &str);
}

/// One row of `metrics.csv`: one per iteration, in order. The last iteration's row
/// carries the final evaluation's `nmi`, `ent` and `normalized_reward` (the periodic
/// evaluation is skipped there); a run stopped before its first iteration writes a
/// single row of iteration 0 with the final evaluation of the untrained policy.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct IterationLog {
    /// Iteration index (1-based).
    pub iteration: usize,
    /// Environment steps so far.
    pub env_steps: usize,
    /// Wall seconds since training start.
    pub wall_s: f64,
    /// Seconds of this iteration's rollout.
    pub rollout_s: f64,
    /// Seconds of this iteration's D/Q updates.
    pub disc_s: f64,
    /// Seconds of this iteration's reward, GAE and PPO.
    pub ppo_s: f64,
    /// `losses/disc_bce`.
    pub disc_bce: f64,
    /// D's accuracy on expert samples of the last batch.
    pub d_acc_expert: f64,
    /// D's accuracy on policy samples of the last batch.
    pub d_acc_policy: f64,
    /// `losses/qc_labeled`.
    pub qc_labeled: f64,
    /// `losses/qc_generated`.
    pub qc_generated: f64,
    /// `losses/qeps`.
    pub qeps: f64,
    /// `losses/rim_cond_entropy`.
    pub rim_entropy: f64,
    /// `losses/rim_marginal_kl`.
    pub rim_kl: f64,
    /// `losses/contrastive`.
    pub contrastive: f64,
    /// Mean policy reward.
    pub reward_mean: f64,
    /// PPO statistics.
    pub policy_loss: f64,
    /// Value loss.
    pub value_loss: f64,
    /// Policy entropy.
    pub entropy: f64,
    /// Approximate KL of the update.
    pub approx_kl: f64,
    /// p(c) as `p0;p1;...`.
    pub prior: String,
    /// NMI if evaluated at this iteration.
    pub nmi: Option<f64>,
    /// ENT if evaluated.
    pub ent: Option<f64>,
    /// Normalised task reward if evaluated.
    pub normalized_reward: Option<f64>,
}

/// What `summary.json` holds.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Method (preset) name.
    pub method: String,
    /// Environment.
    pub env: String,
    /// Training seed.
    pub seed: u64,
    /// Final NMI.
    pub nmi: f64,
    /// Final ENT.
    pub ent: f64,
    /// Final normalised task reward.
    pub normalized_reward: f64,
    /// Environment steps of training.
    pub env_steps: usize,
    /// Iterations run.
    pub iterations: usize,
    /// Wall seconds of training (set-up and final evaluation excluded).
    pub wall_seconds: f64,
    /// Wall seconds including set-up and evaluation.
    pub total_seconds: f64,
    /// End-to-end training env steps per second.
    pub env_steps_per_second: f64,
    /// Mean seconds per iteration of rollout, D/Q updates and PPO.
    pub seconds_per_iteration: PhaseSeconds,
    /// Learned p(c).
    pub prior: Vec<f32>,
    /// Behaviour classifier's held-out accuracy on expert data.
    pub classifier_accuracy: f64,
    /// Q_c's accuracy on the unlabeled expert data against the true modes (paper
    /// Fig. 6): how well the few labels taught the encoder.
    pub encoder_accuracy: EncoderAccuracy,
    /// Final evaluation in full.
    pub eval: EvalResult,
    /// Whether the run was stopped early (Ctrl-C).
    pub interrupted: bool,
}

/// Accuracy of `argmax Q_c(s, a)` against the true mode on expert data.
#[derive(Debug, Clone, Default, Serialize)]
pub struct EncoderAccuracy {
    /// Over all steps (dominated by the majority modes).
    pub overall: f64,
    /// Mean of the per-mode recalls (every mode counts the same).
    pub balanced: f64,
    /// Recall of each mode (NaN-free: a mode without steps reports 0).
    pub per_mode: Vec<f64>,
}

/// [`EncoderAccuracy`] of `disc`'s Q_c head on inputs `x` (`[n, obs+act]`, normalised)
/// with true modes `mode` (`[n]`, int64), in batches so memory stays flat.
fn encoder_accuracy(disc: &Discriminator, x: &Tensor, mode: &Tensor, k: usize) -> EncoderAccuracy {
    let n = x.size()[0];
    let mut hits = vec![0u64; k];
    let mut counts = vec![0u64; k];
    let _guard = tch::no_grad_guard();
    let mut start = 0;
    while start < n {
        let len = (n - start).min(65_536);
        let pred = disc
            .forward(&x.narrow(0, start, len))
            .qc_logits
            .argmax(-1, false);
        let truth = mode.narrow(0, start, len);
        let p: Vec<i64> = Vec::try_from(&pred).unwrap_or_default();
        let t: Vec<i64> = Vec::try_from(&truth).unwrap_or_default();
        for (p, t) in p.iter().zip(&t) {
            if let Ok(t) = usize::try_from(*t)
                && t < k
            {
                counts[t] += 1;
                hits[t] += u64::from(p == &(t as i64));
            }
        }
        start += len;
    }
    let per_mode: Vec<f64> = hits
        .iter()
        .zip(&counts)
        .map(|(&h, &c)| if c == 0 { 0.0 } else { h as f64 / c as f64 })
        .collect();
    let total: u64 = counts.iter().sum();
    EncoderAccuracy {
        overall: hits.iter().sum::<u64>() as f64 / total.max(1) as f64,
        balanced: per_mode.iter().sum::<f64>() / k.max(1) as f64,
        per_mode,
    }
}

/// Per-phase seconds.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct PhaseSeconds {
    /// Rollout.
    pub rollout: f64,
    /// D/Q updates.
    pub disc: f64,
    /// Reward, GAE and PPO.
    pub ppo: f64,
}

/// Expert data as tensors.
struct ExpertData {
    /// `[n, cols+act]` normalised unlabeled inputs (`cols`: `disc.obs_prefix`).
    unlabeled: Tensor,
    /// `[n]` true modes (only for the full-label baseline).
    unlabeled_mode: Tensor,
    /// `[m, cols+act]` labeled inputs.
    labeled: Tensor,
    /// `[m]` labels.
    labels: Tensor,
}

/// `[n, obs_dim]` observations normalised with the expert statistics.
fn norm_obs(obs: &[f32], mean: &[f32], std: &[f32]) -> Tensor {
    let mut v = obs.to_vec();
    crate::classifier::normalize_rows(&mut v, mean, std);
    tensor_2d(&v, mean.len())
}

/// Discriminator inputs `[norm(s)[..cols], a]` from normalised observations and
/// actions (`cols`: the observation entries D reads, `disc.obs_prefix`).
fn disc_inputs(obs_n: &Tensor, cols: usize, act: &[f32], ad: usize) -> Tensor {
    Tensor::cat(&[&obs_n.narrow(1, 0, cols as i64), &tensor_2d(act, ad)], 1)
}

fn scalar(t: &Tensor) -> f64 {
    f64::try_from(t).unwrap_or(f64::NAN)
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
            bail!(
                "{}: dataset is for env `{}` with {} modes, config asks env.name = `{}`, env.n_modes = {}",
                path.display(),
                d.meta.env,
                d.meta.n_modes,
                cfg.env.name,
                cfg.env.n_modes
            );
        }
        Ok(d)
    }
}

/// Everything `run` produced.
pub struct RunOutput {
    /// The summary (also written to `summary.json`).
    pub summary: Summary,
}

/// Seed of actor `i`'s random stream: the same on both transports, so one actor process
/// reproduces one actor thread step for step.
pub fn actor_seed(seed: u64, i: usize) -> u64 {
    seed.wrapping_mul(1_000_003).wrapping_add(i as u64)
}

/// The run's actors: threads of this process, or `ess-actor` processes over iceoryx2
/// shared memory (`run.transport`).
fn rollout_source(
    cfg: &CheckedConfig,
    latent: LatentSpec,
    k: usize,
) -> Result<Box<dyn RolloutSource>> {
    let n = cfg.run.actors;
    let seeds: Vec<u64> = (0..n).map(|i| actor_seed(cfg.run.seed, i)).collect();
    match cfg.run.transport {
        ActorTransport::Threads => {
            let workers: Vec<Worker> = seeds
                .iter()
                .map(|&s| -> Result<Worker> {
                    let env = make_env(&cfg.env.name, cfg.env.n_modes)?;
                    Ok(Worker::new(env, s, k))
                })
                .collect::<Result<_>>()?;
            Ok(Box::new(ThreadedActors::new(workers, latent)))
        }
        ActorTransport::Processes => {
            let actors = ShmActors::new(ShmActorsConfig {
                run_id: new_run_id(),
                binary: actor_binary()?,
                env: cfg.env.name.clone(),
                n_modes: cfg.env.n_modes,
                latent,
                max_steps: cfg.run.rollout_steps.div_ceil(n),
                seeds,
                heartbeat_timeout: std::time::Duration::from_secs_f64(cfg.run.actor_timeout_s),
                // Process start and env construction (MuJoCo model, expert weights).
                startup_timeout: std::time::Duration::from_secs(30),
                plain_env: false,
                task_mode: None,
            })?;
            tracing::info!(run_id = actors.run_id(), pids = ?actors.pids(), "actor processes started");
            Ok(Box::new(actors))
        }
    }
}

/// [`evaluate`] where the run's episodes run: in the actor processes when the actors
/// offer it, else in this process on `env` (the threaded path).
fn evaluate_on(
    reference: &crate::eval::Reference,
    actors: &mut dyn RolloutSource,
    env: &mut dyn ess_envs::ScriptedExpert,
    w: &PolicyWeights,
    latent: &LatentSpec,
    episodes: usize,
    seed: u64,
) -> Result<(EvalResult, Vec<ess_actor::EvalEpisode>)> {
    match actors.evaluator() {
        Some(runner) => evaluate(reference, runner, w, latent, episodes, seed),
        None => evaluate(reference, &mut LocalEval(env), w, latent, episodes, seed),
    }
}

/// Trains with `cfg`, writing into `out`; stops early (and still writes everything)
/// when `shutdown` is set: the current iteration finishes, a checkpoint is saved, the
/// final evaluation runs and `summary.json` says `"interrupted": true`.
pub fn run(
    cfg: &CheckedConfig,
    out: &Path,
    progress: &mut dyn Progress,
    shutdown: &AtomicBool,
) -> Result<RunOutput> {
    run_from(cfg, out, progress, shutdown, false)
}

/// The configuration a run in `out` was started with (its `config.toml`).
pub fn run_config(out: &Path) -> Result<CheckedConfig> {
    let p = out.join("config.toml");
    let text = std::fs::read_to_string(&p).with_context(|| {
        format!(
            "reading {} (is {} the output directory of an `ess train` run?)",
            p.display(),
            out.display()
        )
    })?;
    let mut b = ess_proto::config::ConfigBuilder::new();
    b.merge_toml(&p.display().to_string(), &text)?;
    Ok(b.build()?)
}

/// Continues the run in `out` from its latest checkpoint
/// ([`crate::checkpoint`]) with the configuration it was started with, appending to its
/// `metrics.csv`. The continued run is bit-identical to one never stopped (on the
/// threaded transport; actor processes start fresh episodes, see
/// [`crate::checkpoint::TrainState::actors`]).
pub fn resume(out: &Path, progress: &mut dyn Progress, shutdown: &AtomicBool) -> Result<RunOutput> {
    let cfg = run_config(out)?;
    run_from(&cfg, out, progress, shutdown, true)
}

/// Seed of libtorch's random stream for iteration `it`: re-seeded every iteration, so a
/// resumed run draws what the uninterrupted one drew.
fn torch_seed(seed: u64, it: usize) -> i64 {
    seed.wrapping_mul(0x2545_F491_4F6C_DD1D)
        .wrapping_add(it as u64) as i64
}

/// Keeps the header and the rows of iterations before `next` of `metrics.csv` (rows
/// written after the checkpoint that is resumed from are dropped).
fn truncate_metrics(path: &Path, next: usize) -> Result<()> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading {} to resume", path.display()))?;
    let mut kept = String::new();
    for (i, line) in text.lines().enumerate() {
        let keep = i == 0
            || line
                .split(',')
                .next()
                .and_then(|f| f.parse::<usize>().ok())
                .is_some_and(|it| it < next);
        if keep {
            kept.push_str(line);
            kept.push('\n');
        }
    }
    write_atomic(path, kept.as_bytes())
}

/// A configuration that the env it names cannot take; the CLI exits 2 on it.
#[derive(Debug, thiserror::Error)]
pub enum TrainInputError {
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
}

fn run_from(
    cfg: &CheckedConfig,
    out: &Path,
    progress: &mut dyn Progress,
    shutdown: &AtomicBool,
    resuming: bool,
) -> Result<RunOutput> {
    let t_total = Instant::now();
    // Checked before anything is written or the demonstrations (minutes) generated.
    let mut eval_env = make_env(&cfg.env.name, cfg.env.n_modes)?;
    let spec = eval_env.spec().clone();
    let dcols = crate::nets::obs_columns(cfg.disc.obs_prefix, spec.obs_dim).ok_or_else(|| {
        TrainInputError::DiscObsPrefix {
            prefix: cfg.disc.obs_prefix,
            env: spec.name.clone(),
            obs_dim: spec.obs_dim,
        }
    })?;
    std::fs::create_dir_all(out)
        .with_context(|| format!("creating output dir {}", out.display()))?;
    if !resuming {
        std::fs::write(out.join("config.toml"), cfg.to_toml())
            .with_context(|| format!("writing {}", out.join("config.toml").display()))?;
    }
    let seed = cfg.run.seed;
    let threads = if cfg.run.torch_threads > 0 {
        cfg.run.torch_threads
    } else {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    };
    tch::set_num_threads(threads as i32);
    tch::manual_seed(seed as i64);
    let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 1);

    progress.message("demonstrations");
    let demos = load_or_generate_demos(cfg)?;
    if demos.meta.obs_dim != spec.obs_dim || demos.meta.act_dim != spec.act_dim {
        bail!(
            "dataset dims obs {} / act {} do not match env `{}` (obs {} / act {})",
            demos.meta.obs_dim,
            demos.meta.act_dim,
            spec.name,
            spec.obs_dim,
            spec.act_dim
        );
    }
    let (od, ad, k) = (spec.obs_dim, spec.act_dim, cfg.env.n_modes);
    let (obs_mean, obs_std) = crate::classifier::feature_stats(&demos.unlabeled.obs, od);
    let expert = ExpertData {
        unlabeled: disc_inputs(
            &norm_obs(&demos.unlabeled.obs, &obs_mean, &obs_std),
            dcols,
            &demos.unlabeled.act,
            ad,
        ),
        unlabeled_mode: Tensor::from_slice(
            &demos
                .unlabeled
                .mode
                .iter()
                .map(|&m| m as i64)
                .collect::<Vec<_>>(),
        ),
        labeled: disc_inputs(
            &norm_obs(&demos.labeled.obs, &obs_mean, &obs_std),
            dcols,
            &demos.labeled.act,
            ad,
        ),
        labels: Tensor::from_slice(
            &demos
                .labeled
                .mode
                .iter()
                .map(|&m| m as i64)
                .collect::<Vec<_>>(),
        ),
    };
    let n_exp = demos.unlabeled.len() as i64;
    let n_lab = demos.labeled.len() as i64;

    progress.message("behaviour classifier");
    let reference = build_reference(
        eval_env.as_mut(),
        cfg.run.reference_episodes.max(1),
        cfg.demos.seed ^ 0xC1A5,
    )?;

    let m = &cfg.method;
    let latent = LatentSpec {
        prior: m.prior,
        n_codes: k,
        tau: m.gumbel_tau as f32,
        use_eps: m.use_eps,
    };
    let input = od + 1 + k;
    let mut vs = nn::VarStore::new(tch::Device::Cpu);
    let mut prior_vs = nn::VarStore::new(tch::Device::Cpu);
    let mut dvs = nn::VarStore::new(tch::Device::Cpu);
    let mut ppo = PpoLearner::new(
        &vs,
        &prior_vs,
        input,
        ad,
        k,
        &cfg.ppo,
        m.prior,
        m.gumbel_tau,
    )?;
    let disc = Discriminator::new(dvs.root() / "disc", dcols + ad, &cfg.disc.hidden, k);
    let mut dopt = crate::optim::Adam::new(&dvs, cfg.disc.lr)?;

    let mut actors = rollout_source(cfg, latent, k)?;

    let ckpt_dir = out.join("checkpoints");
    std::fs::create_dir_all(&ckpt_dir)?;
    let mut env_steps = 0usize;
    // Q_c's running estimate of the demos' mode marginal (`method.disc_code_reweight`).
    let mut qc_marginal = vec![1.0 / k as f64; k];
    let mut phases = PhaseSeconds::default();
    let mut iters_done = 0;
    let mut interrupted = false;
    let mut curve: Vec<crate::report::CurvePoint> = Vec::new();
    // Each row is written once the next iteration has run, so that the last one can
    // take the final evaluation's numbers.
    let mut pending: Option<IterationLog> = None;
    let mut scaler = crate::ppo::RewardScaler::default();
    let mut wall_before = 0.0;
    let mut last_saved = None;
    let metrics_path = out.join("metrics.csv");
    if resuming {
        let dir = crate::checkpoint::latest(&ckpt_dir)?.with_context(|| {
            format!(
                "no complete checkpoint under {} to resume from",
                ckpt_dir.display()
            )
        })?;
        progress.message(&format!("resuming from {}", dir.display()));
        let st = crate::checkpoint::load(
            &dir,
            [&mut vs, &mut prior_vs, &mut dvs],
            [&mut ppo.opt, &mut ppo.prior_opt, &mut dopt],
        )?;
        if st.qc_marginal.len() != k {
            bail!(
                "{}: qc_marginal has {} values for env.n_modes = {k}",
                dir.display(),
                st.qc_marginal.len()
            );
        }
        if st.actors.is_empty() {
            tracing::warn!(
                checkpoint = %dir.display(),
                "the checkpoint holds no actor states: actors start fresh episodes, so the resumed run is not bit-identical to an uninterrupted one"
            );
        } else {
            let states = st
                .actors
                .iter()
                .map(|a| a.to_state())
                .collect::<Result<Vec<_>>>()?;
            actors
                .restore(&states)
                .with_context(|| format!("{}: restoring the actors", dir.display()))?;
        }
        rng = st.rng.rng()?;
        env_steps = st.env_steps;
        qc_marginal = st.qc_marginal;
        phases = st.phases;
        iters_done = st.iteration;
        curve = st.curve;
        pending = st.pending;
        scaler = st.scaler;
        wall_before = st.wall_s;
        last_saved = Some(st.iteration);
        truncate_metrics(&metrics_path, st.iteration)?;
    } else {
        std::fs::write(&metrics_path, format!("{CSV_HEADER}\n"))
            .with_context(|| format!("creating {}", metrics_path.display()))?;
    }
    // Finished on every way out of this function (drop), see `crate::runlog`.
    let mut runlog = if resuming {
        crate::runlog::RunLog::reopen(&out.join("run.mcap"), cfg, iters_done)?
    } else {
        crate::runlog::RunLog::create(&out.join("run.mcap"), cfg)?
    };
    let mut csv = std::io::BufWriter::new(
        std::fs::OpenOptions::new()
            .append(true)
            .open(&metrics_path)
            .with_context(|| format!("opening {}", metrics_path.display()))?,
    );

    progress.message("training");
    let t_train = Instant::now();
    // Saves everything a resume needs after `$it` iterations (see `crate::checkpoint`).
    macro_rules! save_checkpoint {
        ($it:expr, $wall:expr) => {{
            csv.flush()?;
            let mut st = crate::checkpoint::TrainState {
                format: crate::checkpoint::FORMAT,
                iteration: $it,
                env_steps,
                wall_s: $wall,
                phases: phases.clone(),
                curve: curve.clone(),
                pending: pending.clone(),
                rng: crate::checkpoint::RngState::of(&rng),
                qc_marginal: qc_marginal.clone(),
                scaler: scaler.clone(),
                adam_steps: Default::default(),
                actors: actor_states(actors.as_mut()),
            };
            crate::checkpoint::save(
                &ckpt_dir,
                [&vs, &prior_vs, &dvs],
                [&ppo.opt, &ppo.prior_opt, &dopt],
                &mut st,
            )?;
        }};
    }
    for it in iters_done + 1..=cfg.run.iterations {
        if shutdown.load(Ordering::Relaxed) {
            interrupted = true;
            break;
        }
        tch::manual_seed(torch_seed(seed, it));
        let mut log = IterationLog {
            iteration: it,
            ..Default::default()
        };
        // --- rollout ---------------------------------------------------------------
        let t0 = Instant::now();
        let weights = Arc::new(export_policy(
            &ppo.policy,
            &ppo.prior_logits,
            &obs_mean,
            &obs_std,
            it as u64,
        )?);
        let chunks = actors.collect(weights.clone(), cfg.run.rollout_steps)?;
        let mut all = Chunk::with_capacity(od, ad, k, cfg.run.rollout_steps);
        for c in &chunks {
            if c.policy_version != weights.version {
                bail!(
                    "chunk of policy version {} in iteration {it}",
                    c.policy_version
                );
            }
            all.extend(c);
        }
        env_steps += all.len();
        log.rollout_s = t0.elapsed().as_secs_f64();

        // --- discriminator and encoders ----------------------------------------------
        let t1 = Instant::now();
        let obs_n = norm_obs(&all.obs, &obs_mean, &obs_std);
        let gen_x = disc_inputs(&obs_n, dcols, &all.act, ad);
        let gen_code = tensor_2d(&all.code, k);
        let gen_eps = Tensor::from_slice(&all.eps);
        let n_gen = all.len() as i64;
        let rim_w = if m.rim_warmup_iters == 0 {
            m.w_rim
        } else {
            m.w_rim * ((it as f64) / m.rim_warmup_iters as f64).min(1.0)
        };
        // Eq. 9 minimises L_RIM over p(c) too: with a learnable prior, the KL term of
        // Eq. 8 pulls p(c) toward Q_c's label marginal on the unlabeled expert data.
        let prior_from_rim = m.prior == LatentPrior::Gumbel && m.rim_prior_grad;
        let batch = cfg.disc.batch as i64;
        let gen_draw = m
            .disc_code_reweight
            .then(|| CodeReweight::new(&all.code, k, &qc_marginal));
        for step in 0..cfg.disc.steps {
            let gi = match &gen_draw {
                Some(d) => Tensor::from_slice(&d.sample(&mut rng, batch)),
                None => Tensor::from_slice(&sample_idx(&mut rng, n_gen, batch)),
            };
            let ei = Tensor::from_slice(&sample_idx(&mut rng, n_exp, batch));
            let xg = gen_x.index_select(0, &gi);
            let xe = expert.unlabeled.index_select(0, &ei);
            let xe = if m.w_grad_penalty > 0.0 {
                xe.set_requires_grad(true)
            } else {
                xe
            };
            let og = disc.forward(&xg);
            let oe = disc.forward(&xe);
            if m.disc_code_reweight {
                // Running estimate of the mode marginal of the unlabeled demos.
                let p = tensor_to_vec(&tch::no_grad(|| {
                    oe.qc_logits
                        .softmax(-1, Kind::Float)
                        .mean_dim(0, false, Kind::Float)
                }));
                for (q, p) in qc_marginal.iter_mut().zip(&p) {
                    *q = 0.99 * *q + 0.01 * f64::from(*p);
                }
            }
            let mut loss = Tensor::from(0.0f32);
            let bce = disc_bce(&oe.d_logit, &og.d_logit);
            loss += &bce * m.w_disc;
            if m.w_grad_penalty > 0.0 {
                loss += r1_penalty(&xe, &oe.d_logit) * m.w_grad_penalty;
            }
            let last = step + 1 == cfg.disc.steps;
            if m.w_qeps > 0.0 {
                let l = qeps_mae(&og.qeps, &gen_eps.index_select(0, &gi));
                if last {
                    log.qeps = scalar(&l);
                }
                loss += l * m.w_qeps;
            }
            if m.w_qc_generated > 0.0 {
                let l = soft_cross_entropy(&og.qc_logits, &gen_code.index_select(0, &gi));
                if last {
                    log.qc_generated = scalar(&l);
                }
                loss += l * m.w_qc_generated;
            }
            if m.w_qc_full_labels > 0.0 {
                let l =
                    hard_cross_entropy(&oe.qc_logits, &expert.unlabeled_mode.index_select(0, &ei));
                loss += l * m.w_qc_full_labels;
            }
            if m.w_qc_labeled > 0.0 && n_lab > 0 {
                let li = Tensor::from_slice(&sample_idx(&mut rng, n_lab, batch.min(n_lab)));
                let ol = disc.forward(&expert.labeled.index_select(0, &li));
                let l = hard_cross_entropy(&ol.qc_logits, &expert.labels.index_select(0, &li));
                if last {
                    log.qc_labeled = scalar(&l);
                }
                loss += l * m.w_qc_labeled;
            }
            if rim_w > 0.0 {
                let log_prior = ppo.prior_logits.log_softmax(-1, Kind::Float);
                let log_prior = if prior_from_rim {
                    log_prior
                } else {
                    log_prior.detach()
                };
                let r = rim(&oe.qc_logits, &log_prior, &disc.encoder_params());
                if last {
                    log.rim_entropy = scalar(&r.cond_entropy);
                    log.rim_kl = scalar(&r.marginal_kl);
                }
                loss += r.weighted(m.rim_cond_entropy, m.rim_marginal_kl, m.rim_l2) * rim_w;
            }
            if m.w_contrastive > 0.0 {
                let nc = (m.contrastive_batch as i64).min(batch);
                let xc = xe.detach().narrow(0, 0, nc);
                let noisy = &xc + xc.randn_like() * m.contrastive_noise;
                let z2 = disc.forward(&noisy).qc_logits;
                let l = nt_xent(
                    &oe.qc_logits.narrow(0, 0, nc),
                    &z2,
                    m.contrastive_temperature,
                );
                if last {
                    log.contrastive = scalar(&l);
                }
                loss += l * m.w_contrastive;
            }
            dopt.zero_grad();
            if prior_from_rim {
                ppo.prior_opt.zero_grad();
            }
            loss.backward();
            dopt.step();
            if prior_from_rim && rim_w > 0.0 {
                ppo.prior_opt.step();
            }
            if last {
                tch::no_grad(|| {
                    log.disc_bce = scalar(&bce);
                    log.d_acc_expert =
                        scalar(&oe.d_logit.gt(0.0).to_kind(Kind::Float).mean(Kind::Float));
                    log.d_acc_policy =
                        scalar(&og.d_logit.le(0.0).to_kind(Kind::Float).mean(Kind::Float));
                });
            }
        }
        log.disc_s = t1.elapsed().as_secs_f64();

        // --- reward, GAE, PPO --------------------------------------------------------
        let t2 = Instant::now();
        let info_w = if m.info_reward_warmup_iters == 0 {
            1.0
        } else {
            ((it as f64) / m.info_reward_warmup_iters as f64).min(1.0)
        };
        let rw = RewardWeights {
            disc_logit: m.disc_reward == ess_proto::config::DiscReward::Logit,
            disc: m.reward_disc,
            qc: m.reward_qc * info_w,
            qc_offset: if m.qc_reward_entropy {
                crate::metrics::entropy(ppo.prior_probs().into_iter().map(f64::from))
            } else {
                0.0
            },
            qeps: if m.use_eps {
                m.reward_qeps * info_w
            } else {
                0.0
            },
        };
        let next_n = norm_obs(&all.next_obs, &obs_mean, &obs_std);
        let eps_col = column(&all.eps);
        let (rewards, values, next_values, disc_r) = tch::no_grad(|| {
            let o = disc.forward(&gen_x);
            let r = policy_reward(rw, &o.d_logit, &o.qc_logits, &gen_code, &o.qeps, &gen_eps);
            let dr = disc_term(rw, &o.d_logit);
            let vin = Tensor::cat(&[&obs_n, &eps_col, &gen_code], 1);
            let nin = Tensor::cat(&[&next_n, &eps_col, &gen_code], 1);
            (
                tensor_to_vec(&r),
                tensor_to_vec(&ppo.values(&vin)),
                tensor_to_vec(&ppo.values(&nin)),
                dr,
            )
        });
        if m.prior == ess_proto::config::LatentPrior::Gumbel && m.prior_score_coef > 0.0 {
            ppo.prior_score_step(&gen_code, &disc_r, m.prior_score_coef);
        }
        let rewards: Vec<f32> = rewards
            .iter()
            .zip(&all.env_reward)
            .map(|(r, e)| r + e)
            .collect();
        log.reward_mean =
            rewards.iter().map(|&r| r as f64).sum::<f64>() / rewards.len().max(1) as f64;
        runlog.chunks(it, &chunks, &rewards)?;
        let (adv, ret) = rollout_gae(
            &cfg.ppo,
            &mut scaler,
            &chunks,
            &rewards,
            &values,
            &next_values,
        );
        let batch = PpoBatch {
            obs: obs_n,
            eps: eps_col,
            code: gen_code,
            gumbel: tensor_2d(&all.gumbel, k),
            pre_tanh: tensor_2d(&all.pre_tanh, ad),
            old_logp: Tensor::from_slice(&all.logp),
            adv: Tensor::from_slice(&adv),
            returns: Tensor::from_slice(&ret),
        };
        let st: PpoStats = ppo.update(&batch, &mut rng);
        log.policy_loss = st.policy_loss;
        log.value_loss = st.value_loss;
        log.entropy = st.entropy;
        log.approx_kl = st.approx_kl;
        log.ppo_s = t2.elapsed().as_secs_f64();
        log.prior = ppo
            .prior_probs()
            .iter()
            .map(|p| format!("{p:.4}"))
            .collect::<Vec<_>>()
            .join(";");
        phases.rollout += log.rollout_s;
        phases.disc += log.disc_s;
        phases.ppo += log.ppo_s;
        log.env_steps = env_steps;
        log.wall_s = wall_before + t_train.elapsed().as_secs_f64();
        iters_done = it;

        if cfg.run.eval_every > 0
            && it.is_multiple_of(cfg.run.eval_every)
            && it != cfg.run.iterations
        {
            let w = export_policy(
                &ppo.policy,
                &ppo.prior_logits,
                &obs_mean,
                &obs_std,
                it as u64,
            )?;
            let (r, eval_episodes) = evaluate_on(
                &reference,
                actors.as_mut(),
                eval_env.as_mut(),
                &w,
                &latent,
                cfg.run.eval_episodes_periodic,
                seed ^ 0xE7A1,
            )?;
            runlog.eval_episodes(it, false, &eval_episodes)?;
            curve.push((env_steps, r.nmi, r.ent, r.normalized_reward));
            log.nmi = Some(r.nmi);
            log.ent = Some(r.ent);
            log.normalized_reward = Some(r.normalized_reward);
        }
        progress.iteration(&log);
        runlog.iteration(&log)?;
        if let Some(done) = pending.replace(log) {
            write_csv_row(&mut csv, &done)?;
        }
        if cfg.run.checkpoint_every > 0 && it.is_multiple_of(cfg.run.checkpoint_every) {
            save_checkpoint!(it, wall_before + t_train.elapsed().as_secs_f64());
            last_saved = Some(it);
        }
    }
    let wall = wall_before + t_train.elapsed().as_secs_f64();
    if last_saved != Some(iters_done) {
        save_checkpoint!(iters_done, wall);
    }

    progress.message("final evaluation");
    let w: PolicyWeights = export_policy(
        &ppo.policy,
        &ppo.prior_logits,
        &obs_mean,
        &obs_std,
        iters_done as u64,
    )?;
    let (result, episodes) = evaluate_on(
        &reference,
        actors.as_mut(),
        eval_env.as_mut(),
        &w,
        &latent,
        cfg.run.eval_episodes,
        seed ^ 0xF1AA,
    )?;
    runlog.eval_episodes(iters_done, true, &episodes)?;
    // The final evaluation completes the last iteration's row (no iteration ran: a
    // row of iteration 0 for the untrained policy).
    let mut last = pending.unwrap_or_else(|| IterationLog {
        wall_s: wall,
        prior: ppo
            .prior_probs()
            .iter()
            .map(|p| format!("{p:.4}"))
            .collect::<Vec<_>>()
            .join(";"),
        ..Default::default()
    });
    last.nmi = Some(result.nmi);
    last.ent = Some(result.ent);
    last.normalized_reward = Some(result.normalized_reward);
    write_csv_row(&mut csv, &last)?;
    csv.flush()?;
    runlog.iteration(&last)?;
    runlog.finish()?;

    if spec.name == "traj2d" {
        crate::report::plot_traj2d(
            &out.join("trajectories.png"),
            &demos,
            &episodes,
            &cfg.method.name,
            k,
        )?;
    }
    curve.push((env_steps, result.nmi, result.ent, result.normalized_reward));
    crate::report::plot_curves(&out.join("curves.png"), &cfg.method.name, &curve)?;

    let n = iters_done.max(1) as f64;
    let summary = Summary {
        method: cfg.method.name.clone(),
        env: cfg.env.name.clone(),
        seed,
        nmi: result.nmi,
        ent: result.ent,
        normalized_reward: result.normalized_reward,
        env_steps,
        iterations: iters_done,
        wall_seconds: wall,
        total_seconds: t_total.elapsed().as_secs_f64(),
        env_steps_per_second: env_steps as f64 / wall.max(1e-9),
        seconds_per_iteration: PhaseSeconds {
            rollout: phases.rollout / n,
            disc: phases.disc / n,
            ppo: phases.ppo / n,
        },
        prior: ppo.prior_probs(),
        classifier_accuracy: reference.classifier_accuracy,
        encoder_accuracy: encoder_accuracy(&disc, &expert.unlabeled, &expert.unlabeled_mode, k),
        eval: result,
        interrupted,
    };
    let json = serde_json::to_string_pretty(&summary)?;
    write_atomic(&out.join("summary.json"), json.as_bytes())?;
    Ok(RunOutput { summary })
}

const CSV_HEADER: &str = "iteration,env_steps,wall_s,rollout_s,disc_s,ppo_s,disc_bce,d_acc_expert,d_acc_policy,qc_labeled,qc_generated,qeps,rim_entropy,rim_kl,contrastive,reward_mean,policy_loss,value_loss,entropy,approx_kl,prior,nmi,ent,normalized_reward";

fn opt(v: Option<f64>) -> String {
    v.map(|x| format!("{x:.6}")).unwrap_or_default()
}

fn write_csv_row(w: &mut impl Write, l: &IterationLog) -> Result<()> {
    writeln!(
        w,
        "{},{},{:.3},{:.4},{:.4},{:.4},{:.6},{:.4},{:.4},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{},{},{},{}",
        l.iteration,
        l.env_steps,
        l.wall_s,
        l.rollout_s,
        l.disc_s,
        l.ppo_s,
        l.disc_bce,
        l.d_acc_expert,
        l.d_acc_policy,
        l.qc_labeled,
        l.qc_generated,
        l.qeps,
        l.rim_entropy,
        l.rim_kl,
        l.contrastive,
        l.reward_mean,
        l.policy_loss,
        l.value_loss,
        l.entropy,
        l.approx_kl,
        l.prior,
        opt(l.nmi),
        opt(l.ent),
        opt(l.normalized_reward)
    )?;
    Ok(())
}

/// Draws generated transitions so that code `j` (its episode's `argmax c`) makes up a
/// share `target[j]` of the batch (`method.disc_code_reweight`).
struct CodeReweight {
    /// Cumulative sampling weights, one per transition.
    cumulative: Vec<f64>,
}

impl CodeReweight {
    fn new(code: &[f32], k: usize, target: &[f64]) -> Self {
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

    fn sample(&self, rng: &mut ChaCha8Rng, batch: i64) -> Vec<i64> {
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

fn sample_idx(rng: &mut ChaCha8Rng, n: i64, batch: i64) -> Vec<i64> {
    (0..batch).map(|_| rng.random_range(0..n.max(1))).collect()
}

/// Writes `bytes` to `path` through a temporary file and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming into {}", path.display()))?;
    Ok(())
}

/// The actors' states for a checkpoint; none where the transport does not carry them
/// (actor processes; `--resume` says so) or could not give them (logged).
fn actor_states(actors: &mut dyn RolloutSource) -> Vec<crate::checkpoint::SavedWorker> {
    match actors.snapshot() {
        Ok(Some(states)) => states.iter().map(Into::into).collect(),
        Ok(None) => Vec::new(),
        Err(e) => {
            tracing::warn!(error = %e, "checkpoint without actor states");
            Vec::new()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ess_proto::config::ConfigBuilder;

    struct Quiet;
    impl Progress for Quiet {
        fn iteration(&mut self, _: &IterationLog) {}
        fn message(&mut self, _: &str) {}
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
    fn metrics_csv_has_one_row_per_iteration_and_the_final_evaluation_in_the_last() {
        let mut b = ConfigBuilder::new();
        for kv in [
            "run.iterations=3",
            "run.transport=\"threads\"",
            "run.actors=1",
            "run.eval_every=2",
            "run.rollout_steps=200",
            "disc.steps=2",
            "disc.batch=32",
            "ppo.epochs=1",
            "ppo.minibatch=100",
            "run.eval_episodes=2",
            "run.eval_episodes_periodic=1",
            "run.reference_episodes=2",
            "demos.majority_episodes=4",
            "run.actors=1",
            "run.torch_threads=1",
        ] {
            b.set(kv).expect(kv);
        }
        let cfg = b.build().expect("config");
        let dir = tempfile::tempdir().expect("tmp");
        let out = run(&cfg, dir.path(), &mut Quiet, &AtomicBool::new(false)).expect("train");
        let csv = std::fs::read_to_string(dir.path().join("metrics.csv")).expect("csv");
        let mut lines = csv.lines();
        assert_eq!(lines.next(), Some(CSV_HEADER));
        let col = |name: &str| CSV_HEADER.split(',').position(|c| c == name).expect(name);
        let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
        let iterations: Vec<&str> = rows.iter().map(|r| r[0]).collect();
        assert_eq!(iterations, ["1", "2", "3"], "{csv}");
        // Every row holds its iteration's training numbers.
        for r in &rows {
            for name in ["env_steps", "rollout_s", "ppo_s"] {
                let v: f64 = r[col(name)].parse().expect(name);
                assert!(v > 0.0, "{name} = {v} in {r:?}");
            }
        }
        // Periodic evaluation at iteration 2, the final one in iteration 3's row.
        let nmi = |i: usize| rows[i][col("nmi")];
        assert_eq!(nmi(0), "", "{csv}");
        assert!(!nmi(1).is_empty(), "{csv}");
        let final_nmi: f64 = nmi(2).parse().expect("final nmi");
        assert!((final_nmi - out.summary.nmi).abs() < 1e-6, "{csv}");
        let ent: f64 = rows[2][col("ent")].parse().expect("final ent");
        assert!((ent - out.summary.ent).abs() < 1e-6, "{csv}");
    }

    #[test]
    fn resuming_a_directory_without_a_checkpoint_names_what_is_missing() {
        let small = || {
            let mut b = ConfigBuilder::new();
            b.set("run.iterations=2").expect("set");
            b.set("run.transport=\"threads\"").expect("set");
            b.build().expect("config")
        };
        let dir = tempfile::tempdir().expect("tmp");
        let e = resume(dir.path(), &mut Quiet, &AtomicBool::new(false))
            .err()
            .expect("no run there");
        assert!(format!("{e:#}").contains("config.toml"), "{e:#}");
        std::fs::write(dir.path().join("config.toml"), small().to_toml()).expect("w");
        let e = resume(dir.path(), &mut Quiet, &AtomicBool::new(false))
            .err()
            .expect("no checkpoint");
        assert!(format!("{e:#}").contains("no complete checkpoint"), "{e:#}");
    }
}
