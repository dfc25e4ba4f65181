//! Building a [`Trainer`]: checks, demonstrations, networks, actors, and on `--resume`
//! the latest checkpoint.

use super::bc;
use super::data::{Dims, ExpertData, ObsNorm, TrainInputError, load_or_generate_demos};
use super::records::{CSV_HEADER, OpenSink, RecordSink, ResumedAt, truncate_metrics};
use super::{LoopState, Progress, Trainer};
use crate::actors::{ShmActors, ShmActorsConfig, actor_binary, new_run_id};
use crate::eval::Reference;
use crate::remote::{Assign, RemoteActors, RemoteError, RemoteSetup};
use crate::train::nets::Discriminator;
use crate::train::optim::Adam;
use crate::train::ppo::PpoLearner;
use anyhow::{Context, Result, bail};
use ess_actor::{LatentSpec, PolicyWeights, RolloutSource, ThreadedActors, Worker, actor_seed};
use ess_envs::demos::UNKNOWN_MODE;
use ess_envs::{Demos, Env, make_env, make_training_env};
use ess_proto::CheckedConfig;
use ess_proto::config::{ActorTransport, LatentPrior, RolloutCodes};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::io::BufWriter;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tch::nn;

/// The learner's networks and optimisers: policy and value (`vs`), p(c) (`prior_vs`),
/// the discriminator body with its heads (`dvs`).
pub struct Nets {
    /// Policy and value variables.
    pub vs: nn::VarStore,
    /// The p(c) logits.
    pub prior_vs: nn::VarStore,
    /// Discriminator variables.
    pub dvs: nn::VarStore,
    /// PPO (policy, value, p(c) and their optimisers).
    pub ppo: PpoLearner,
    /// D, Q_c, Q_eps.
    pub disc: Discriminator,
    /// The discriminator's optimiser.
    pub dopt: Adam,
}

impl Nets {
    /// Fresh networks for `cfg` (libtorch's generator seeded by the caller).
    pub fn new(cfg: &CheckedConfig, d: Dims) -> Result<Self> {
        let m = &cfg.method;
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let prior_vs = nn::VarStore::new(tch::Device::Cpu);
        let dvs = nn::VarStore::new(tch::Device::Cpu);
        let input = d.obs + 1 + d.codes;
        let ppo = PpoLearner::new(
            &vs,
            &prior_vs,
            input,
            d.act,
            d.codes,
            &cfg.ppo,
            // With uniform rollouts the codes are plain inputs to PPO: p(c) learns
            // from Q_c's label marginal instead of through the surrogate.
            match m.rollout_codes {
                RolloutCodes::Prior => m.prior,
                RolloutCodes::Uniform => LatentPrior::Uniform,
            },
            m.gumbel_tau,
        )?;
        let disc = Discriminator::new(dvs.root() / "disc", d.disc_inp(), &cfg.disc.hidden, d.codes);
        let dopt = Adam::new(&dvs, cfg.disc.lr)?;
        Ok(Self {
            vs,
            prior_vs,
            dvs,
            ppo,
            disc,
            dopt,
        })
    }

    /// What the fused backend reads of these networks.
    pub fn fused_view(&self) -> crate::fused::NetsView<'_> {
        crate::fused::NetsView {
            disc: &self.disc,
            dopt: &self.dopt,
            policy: &self.ppo.policy,
            value: &self.ppo.value,
            opt: &self.ppo.opt,
            prior_opt: &self.ppo.prior_opt,
        }
    }
}

/// True when the run's env is a user's task file (`task:PATH`): it has no experts.
fn is_task(cfg: &CheckedConfig) -> bool {
    ess_envs::task::task_path(&cfg.env.name).is_some()
}

/// The env the actors and the evaluation step ([`make_training_env`]).
pub(crate) fn rollout_env(cfg: &CheckedConfig) -> Result<Box<dyn Env>> {
    Ok(make_training_env(&cfg.env.name, cfg.env.n_modes)?)
}

/// What evaluation scores against: a built-in env's experts roll the reference; a task
/// file has none, so its demonstrations are the reference.
fn reference(cfg: &CheckedConfig, eval_env: &mut dyn Env, demos: &Demos) -> Result<Reference> {
    let (episodes, seed) = (cfg.run.reference_episodes.max(1), cfg.demos.seed ^ 0xC1A5);
    if is_task(cfg) {
        if cfg.method.w_qc_full_labels > 0.0 && demos.unlabeled.mode.contains(&UNKNOWN_MODE) {
            bail!(
                "{}: some unlabeled episodes have no mode, but this preset (full labels) needs every one",
                cfg.demos.path
            );
        }
        return crate::eval::reference_from_demos(eval_env, demos, episodes, seed);
    }
    let mut scripted = make_env(&cfg.env.name, cfg.env.n_modes)?;
    crate::eval::build_reference(scripted.as_mut(), episodes, seed)
}

/// What evaluation measures on a task file, and why.
fn evaluation_note(env: &dyn Env, demos: &Demos) -> String {
    let k = env.spec().n_modes;
    let known = |s: &ess_envs::DemoSplit| s.steps_per_mode(k).iter().sum::<usize>();
    let steps = known(&demos.labeled) + known(&demos.unlabeled);
    let reward = if env.has_mode_rewards() {
        "normalized reward applies (the task file's [[modes]] rewards; expert return = the \
         demonstrations' own, random = random rollouts)"
    } else {
        "normalized reward does not apply (the task file defines no [[modes]] rewards; it reads 0)"
    };
    format!(
        "evaluation: NMI / ENT with a behaviour classifier trained on the {steps} demonstration \
         steps of known mode; {reward}"
    )
}

/// The run's actors: threads of this process, or `ess-actor` processes over iceoryx2
/// shared memory (`run.transport`); with `[remote]`, those plus actor hosts on other
/// machines ([`crate::remote`]).
fn rollout_source(
    cfg: &CheckedConfig,
    latent: LatentSpec,
    k: usize,
) -> Result<Box<dyn RolloutSource>> {
    let local = local_rollout_source(cfg, latent, k)?;
    if !cfg.remote.enabled() {
        return Ok(local);
    }
    let run = new_run_id();
    let template = Assign {
        run,
        env: cfg.env.name.clone(),
        n_modes: cfg.env.n_modes,
        plain_env: is_task(cfg),
        prior: latent.prior,
        n_codes: latent.n_codes,
        tau: latent.tau,
        use_eps: latent.use_eps,
        first_actor: 0,
        seeds: Vec::new(),
        max_steps: cfg.run.rollout_steps,
        actor_timeout_s: cfg.run.actor_timeout_s,
    };
    let setup = RemoteSetup {
        remote: cfg.remote.clone(),
        run_seed: cfg.run.seed,
        template,
    };
    match RemoteActors::start(local, setup) {
        Ok(r) => Ok(Box::new(r)),
        Err(e @ RemoteError::TlsFile { .. }) => {
            Err(TrainInputError::RemoteTls(e.to_string()).into())
        }
        Err(e) => Err(e.into()),
    }
}

/// This machine's actors.
fn local_rollout_source(
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
                .map(|&s| -> Result<Worker> { Ok(Worker::new(rollout_env(cfg)?, s, k)) })
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
                // With remote hosts, a lost host's share may fall on the local actors.
                max_steps: if cfg.remote.enabled() {
                    cfg.run.rollout_steps
                } else {
                    cfg.run.rollout_steps.div_ceil(n)
                },
                seeds,
                heartbeat_timeout: Duration::from_secs_f64(cfg.run.actor_timeout_s),
                // Process start and env construction (MuJoCo model, expert weights).
                startup_timeout: Duration::from_secs(30),
                plain_env: is_task(cfg),
                task_mode: None,
            })?;
            tracing::info!(run_id = actors.run_id(), pids = ?actors.pids(), "actor processes started");
            Ok(Box::new(actors))
        }
    }
}

/// The learner's threads (`run.torch_threads`, 0: one per core).
fn learner_threads(cfg: &CheckedConfig) -> usize {
    if cfg.run.torch_threads > 0 {
        cfg.run.torch_threads
    } else {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    }
}

/// Sets libtorch's thread count and seeds it.
fn init_torch(cfg: &CheckedConfig) {
    tch::set_num_threads(learner_threads(cfg) as i32);
    tch::manual_seed(cfg.run.seed as i64);
}

/// The fused backend for `nets` when the configuration asks for it and it covers the
/// configuration; otherwise tch, and the run's log says why.
pub(crate) fn fused_backend(
    cfg: &CheckedConfig,
    nets: &Nets,
    progress: &mut dyn Progress,
) -> Result<Option<crate::fused::Fused>> {
    if cfg.learner.backend != ess_proto::config::Backend::Fused {
        return Ok(None);
    }
    if let Some(why) = crate::fused::not_covered(cfg) {
        let msg = format!(
            "learner.backend = \"fused\" does not cover this run ({why}): the update runs on tch"
        );
        tracing::warn!("{msg}");
        progress.message(&msg);
        return Ok(None);
    }
    Ok(Some(crate::fused::Fused::new(
        nets.fused_view(),
        learner_threads(cfg),
    )?))
}

impl LoopState {
    /// A fresh run's state.
    fn fresh(cfg: &CheckedConfig) -> Self {
        let seed = cfg.run.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 1;
        let k = cfg.env.n_modes;
        Self {
            env_steps: 0,
            iters_done: 0,
            phases: Default::default(),
            curve: Vec::new(),
            pending: None,
            rng: ChaCha8Rng::seed_from_u64(seed),
            qc_marginal: vec![1.0 / k as f64; k],
            scaler: Default::default(),
            wall_before: 0.0,
            last_saved: None,
        }
    }

    /// The state of the latest checkpoint under `ckpt_dir`, loading the networks into
    /// `nets` and the actors' states into `actors`.
    fn restore(
        ckpt_dir: &Path,
        nets: &mut Nets,
        actors: &mut dyn RolloutSource,
        k: usize,
        progress: &mut dyn Progress,
    ) -> Result<(Self, Option<Arc<PolicyWeights>>)> {
        let dir = crate::train::checkpoint::latest(ckpt_dir)?.with_context(|| {
            format!(
                "no complete checkpoint under {} to resume from",
                ckpt_dir.display()
            )
        })?;
        progress.message(&format!("resuming from {}", dir.display()));
        let n = nets;
        let st = crate::train::checkpoint::load(
            &dir,
            [&mut n.vs, &mut n.prior_vs, &mut n.dvs],
            [&mut n.ppo.opt, &mut n.ppo.prior_opt, &mut n.dopt],
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
        let behaviour = match st.behaviour.clone() {
            Some(m) => {
                let (w, _) = ess_actor::shm::policy_from_msg(m).with_context(|| {
                    format!("{}: the overlapped rollout's weights", dir.display())
                })?;
                Some(Arc::new(w))
            }
            None => None,
        };
        let state = Self {
            env_steps: st.env_steps,
            iters_done: st.iteration,
            phases: st.phases,
            curve: st.curve,
            pending: st.pending,
            rng: st.rng.rng()?,
            qc_marginal: st.qc_marginal,
            scaler: st.scaler,
            wall_before: st.wall_s,
            last_saved: Some(st.iteration),
        };
        Ok((state, behaviour))
    }
}

/// The behaviour-cloning warm start of a fresh run (`ppo.bc_steps`, [`bc`]).
fn clone_labeled(
    cfg: &CheckedConfig,
    nets: &mut Nets,
    demos: &Demos,
    norm: &ObsNorm,
    d: Dims,
    rng: &mut ChaCha8Rng,
    progress: &mut dyn Progress,
) {
    let shape = (cfg.ppo.bc_steps, cfg.ppo.minibatch);
    let (labeled, use_eps) = (&demos.labeled, cfg.method.use_eps);
    match bc::clone_steps(&mut nets.ppo, labeled, norm, (d, use_eps), shape, rng) {
        Some(l) => progress.message(&format!(
            "behaviour cloning: {} steps on {} labeled transitions, squared error {:.4} -> {:.4}",
            shape.0,
            labeled.mode.len(),
            l.first,
            l.last
        )),
        // Asked for, but the dataset (a user's task file) has no labeled split.
        None if shape.0 > 0 => progress
            .message("behaviour cloning: the dataset has no labeled demonstrations; skipped"),
        None => {}
    }
}

/// `metrics.csv`, created (a fresh run) or cut after the checkpoint's iteration (a
/// resumed one), and the logs `logs` opens beside it.
fn open_logs(
    cfg: &CheckedConfig,
    out: &Path,
    logs: OpenSink,
    st: &LoopState,
    resuming: bool,
) -> Result<(Box<dyn RecordSink>, BufWriter<std::fs::File>)> {
    let metrics = out.join("metrics.csv");
    let sink = if resuming {
        truncate_metrics(&metrics, st.iters_done)?;
        let at = ResumedAt {
            iteration: st.iters_done,
            env_steps: st.env_steps,
        };
        logs(cfg, out, Some(at))?
    } else {
        std::fs::write(&metrics, format!("{CSV_HEADER}\n"))
            .with_context(|| format!("creating {}", metrics.display()))?;
        logs(cfg, out, None)?
    };
    let csv = std::fs::OpenOptions::new()
        .append(true)
        .open(&metrics)
        .with_context(|| format!("opening {}", metrics.display()))?;
    Ok((sink, BufWriter::new(csv)))
}

impl<'c> Trainer<'c> {
    /// A run of `cfg` writing into `out`, or (`resuming`) the run there continued from
    /// its latest checkpoint. Input errors are found before anything is written or the
    /// demonstrations (minutes) are generated.
    pub fn new(
        cfg: &'c CheckedConfig,
        out: &Path,
        logs: OpenSink,
        progress: &mut dyn Progress,
        resuming: bool,
    ) -> Result<Self> {
        let started = Instant::now();
        let mut eval_env = rollout_env(cfg)?;
        let spec = eval_env.spec().clone();
        let dims = Dims::new(cfg, &spec.name, spec.obs_dim, spec.act_dim)?;
        if is_task(cfg) && cfg.demos.path.is_empty() {
            return Err(TrainInputError::TaskNeedsDemos {
                env: cfg.env.name.clone(),
            }
            .into());
        }
        std::fs::create_dir_all(out.join("checkpoints"))
            .with_context(|| format!("creating output dir {}", out.display()))?;
        if !resuming {
            std::fs::write(out.join("config.toml"), cfg.to_toml())
                .with_context(|| format!("writing {}", out.join("config.toml").display()))?;
        }
        init_torch(cfg);
        progress.message("demonstrations");
        let demos = load_or_generate_demos(cfg)?;
        if demos.meta.obs_dim != spec.obs_dim || demos.meta.act_dim != spec.act_dim {
            return Err(TrainInputError::DemosMismatch(format!(
                "{}: dataset dims obs {} / act {} do not match env `{}` (obs {} / act {})",
                cfg.demos.path,
                demos.meta.obs_dim,
                demos.meta.act_dim,
                spec.name,
                spec.obs_dim,
                spec.act_dim
            ))
            .into());
        }
        let (mean, std) = crate::eval::classifier::feature_stats(&demos.unlabeled.obs, dims.obs);
        let norm = ObsNorm { mean, std };
        let expert = ExpertData::new(&demos, &norm, dims);
        progress.message("behaviour classifier");
        let reference = reference(cfg, eval_env.as_mut(), &demos)?;
        if is_task(cfg) {
            progress.message(&evaluation_note(eval_env.as_ref(), &demos));
        }
        let m = &cfg.method;
        let latent = LatentSpec {
            prior: m.prior,
            n_codes: dims.codes,
            tau: m.gumbel_tau as f32,
            use_eps: m.use_eps,
        };
        let mut nets = Nets::new(cfg, dims)?;
        let mut actors = rollout_source(cfg, latent, dims.codes)?;
        let (st, resume_weights) = if resuming {
            let ckpt = out.join("checkpoints");
            LoopState::restore(&ckpt, &mut nets, actors.as_mut(), dims.codes, progress)?
        } else {
            let mut st = LoopState::fresh(cfg);
            clone_labeled(cfg, &mut nets, &demos, &norm, dims, &mut st.rng, progress);
            (st, None)
        };
        let fused = fused_backend(cfg, &nets, progress)?;
        let (mut sink, csv) = open_logs(cfg, out, logs, &st, resuming)?;
        if let Some(note) = sink.note() {
            progress.message(&note);
        }
        Ok(Self {
            cfg,
            out: out.to_owned(),
            spec,
            dims,
            demos,
            norm,
            expert,
            reference,
            latent,
            nets,
            fused,
            actors: Some(actors),
            prefetch: None,
            resume_weights,
            eval_env,
            st,
            csv,
            sink,
            started,
            train_started: Instant::now(),
        })
    }
}
