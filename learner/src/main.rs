//! `ess`: train imitation policies from multi-modal, imbalanced, mostly unlabeled
//! demonstrations (Ess-InfoGAIL and its baselines).
//!
//! Thin binary: parse, set up tracing, call the library. Data goes to stdout, logs and
//! progress to stderr. Exit codes: 0 ok, 1 runtime failure, 2 bad input (arguments,
//! configuration, files).

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use ess_envs::generate_demos;
use ess_learner::experts::{ExpertTrainConfig, eval_experts, train_expert};
use ess_learner::presets::{ConfigLayers, PRESETS};
use ess_learner::progress::{JsonlProgress, ProgressEvent};
use ess_learner::train::{IterationLog, Progress, demo_spec, run};
use ess_proto::config::CheckedConfig;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

#[derive(Parser)]
#[command(
    name = "ess",
    version,
    about = "Semi-supervised multi-modal imitation learning (Ess-InfoGAIL)"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Train a policy with one method; writes config, metrics, checkpoints, summary, plots.
    Train(TrainArgs),
    /// Demonstration datasets.
    Demos {
        #[command(subcommand)]
        cmd: DemosCmd,
    },
    /// Per-mode expert policies (PPO on each mode's task reward).
    Experts {
        #[command(subcommand)]
        cmd: ExpertsCmd,
    },
    /// List the method presets.
    Presets,
    /// Run the job server: a gRPC daemon that owns training jobs on this machine.
    Serve(ServeArgs),
    /// Talk to a job server: submit, list, get, watch, stop, resume jobs.
    Job(JobArgs),
    /// Table 1 view of finished runs: a row per run, mean ± std per env and method
    /// beside the paper's value (Markdown).
    Report {
        /// Run directories (each holding a summary.json).
        #[arg(required = true)]
        runs: Vec<PathBuf>,
    },
    /// The evaluation episodes of a run log (`<out>/run.mcap`): list them, or
    /// re-simulate one from its recorded start state and actions and report the largest
    /// deviation from the recording (exit 1 above --tol).
    Replay(ReplayArgs),
}

#[derive(Args)]
struct ReplayArgs {
    /// The run log (`run.mcap` in a training run's output directory).
    file: PathBuf,
    /// Re-simulate this episode (an index from the listing).
    #[arg(long)]
    episode: Option<u32>,
    /// Largest tolerated absolute deviation of state, observation and mode rewards.
    #[arg(long, default_value_t = 1e-6)]
    tol: f64,
    /// Draw the replayed episode into this PNG (MuJoCo envs also write
    /// `<name>-path.png`); needs --episode.
    #[arg(long, value_name = "PNG")]
    plot: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

#[derive(Subcommand)]
enum ExpertsCmd {
    /// Train one mode's expert with PPO on that mode's task reward (uses the `ppo` and
    /// `run` config sections: rollout_steps, actors, transport, torch_threads, seed).
    Train {
        #[command(flatten)]
        config: ConfigArgs,
        /// Behaviour mode (0-based).
        #[arg(long)]
        mode: usize,
        /// Total env steps (a resumed run counts its earlier steps).
        #[arg(long, default_value_t = 1_000_000)]
        steps: u64,
        /// Expert file (default: deploy/experts/<env>/mode<k>.safetensors, or under
        /// ESS_EXPERTS_DIR).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Continue training the expert at --out from its saved state.
        #[arg(long, conflicts_with = "init_from")]
        resume: bool,
        /// Start from another expert of the same env (any mode; its state file must sit
        /// beside it): its policy, value, normaliser and step count, so --steps counts
        /// its steps too. E.g. a running Humanoid from the balancing one.
        #[arg(long, value_name = "EXPERT")]
        init_from: Option<PathBuf>,
        /// Learner: PPO (the `ppo` and `run` sections) or SAC (the `sac` section and
        /// run.seed / run.torch_threads; one env in this process).
        #[arg(long, value_enum, default_value_t = ExpertAlgo::Ppo)]
        algo: ExpertAlgo,
    },
    /// Each mode's expert against uniformly random actions on its task reward.
    Eval {
        #[command(flatten)]
        config: ConfigArgs,
        /// Directory of `<env>/mode<k>.safetensors` (default: deploy/experts or
        /// ESS_EXPERTS_DIR).
        #[arg(long)]
        dir: Option<PathBuf>,
        /// Episodes per mode and policy.
        #[arg(long, default_value_t = 10)]
        episodes: usize,
        /// Print JSON instead of a Markdown table.
        #[arg(long)]
        json: bool,
    },
}

/// Expert learners of `ess experts train`.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ExpertAlgo {
    /// PPO with GAE, the imitation learner's ([`ess_learner::ppo`]).
    Ppo,
    /// Soft actor-critic ([`ess_learner::sac`]).
    Sac,
}

#[derive(Args)]
struct ConfigArgs {
    /// Method preset (see `ess presets`) or a path to a preset TOML file.
    #[arg(long, default_value = "ess-infogail")]
    preset: String,
    /// A TOML config file applied over the preset.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Environment (overrides env.name).
    #[arg(long)]
    env: Option<String>,
    /// Training seed (overrides run.seed).
    #[arg(long)]
    seed: Option<u64>,
    /// Override a config key, e.g. `--set run.iterations=50` (repeatable; applied last).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
}

#[derive(Args)]
struct TrainArgs {
    #[command(flatten)]
    config: ConfigArgs,
    /// Output directory (default: runs/<preset>-<env>-s<seed>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the resolved configuration and exit.
    #[arg(long)]
    print_config: bool,
    /// Run N actors as `ess-actor` processes over iceoryx2 shared memory (sets
    /// run.actors=N, run.transport="processes"; the default is one per core). 0 runs
    /// one actor as a thread of this process instead (run.actors=1,
    /// run.transport="threads"): the single-process path, whose --resume is
    /// bit-identical.
    #[arg(long, value_name = "N")]
    actors: Option<usize>,
    /// Continue the run in DIR from its latest checkpoint, with the configuration it
    /// was started with (DIR/config.toml); bit-identical to a run never stopped.
    #[arg(
        long,
        value_name = "DIR",
        conflicts_with_all = ["preset", "config", "env", "seed", "set", "out", "actors", "print_config"]
    )]
    resume: Option<PathBuf>,
    /// How progress is reported: `human` (a bar or lines on stderr, a summary on
    /// stdout) or `jsonl` (one JSON object per line on stdout: messages, every
    /// iteration's metrics, the final result; what `ess serve` reads).
    #[arg(long, value_enum, default_value = "human")]
    progress: ProgressFormat,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ProgressFormat {
    Human,
    Jsonl,
}

#[derive(Args)]
struct ServeArgs {
    /// Address to listen on (IP:PORT; port 0 picks a free one). The bound address is
    /// printed as the first line of stdout. A non-loopback address needs --token-file.
    #[arg(long, default_value = ess_learner::serve::DEFAULT_LISTEN)]
    listen: String,
    /// File holding the bearer token every JobService call must carry
    /// (`authorization: Bearer <token>`). Without it, calls are not authenticated.
    #[arg(long)]
    token_file: Option<PathBuf>,
    /// Data directory: one `jobs/<id>/` per job (record, config, log, run outputs).
    #[arg(long, default_value = "ess-jobs")]
    data_dir: PathBuf,
    /// Cores running jobs may hold together (default: the machine's). A job holds
    /// max(run.actors, run.torch_threads, 1) of them; the rest queue.
    #[arg(long)]
    cores: Option<usize>,
    /// Seconds a shutting-down server waits for its stopped jobs before killing them.
    #[arg(long, default_value_t = 600.0)]
    stop_grace_s: f64,
}

#[derive(Args)]
struct JobArgs {
    /// Server URL (default: $ESS_SERVER, else http://127.0.0.1:50551).
    #[arg(long, global = true)]
    server: Option<String>,
    /// File holding the server's bearer token (default: $ESS_TOKEN_FILE, if set).
    #[arg(long, global = true)]
    token_file: Option<PathBuf>,
    /// Print JSON (one object per line for `watch`) instead of text.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    cmd: JobCmd,
}

#[derive(Subcommand)]
enum JobCmd {
    /// Validate and queue a job (the config flags of `ess train`).
    Submit {
        #[command(flatten)]
        config: ConfigArgs,
        /// Then watch it until it ends.
        #[arg(long)]
        watch: bool,
    },
    /// List jobs (oldest first).
    List {
        /// Only jobs in this state (repeatable): queued, running, stopping, stopped,
        /// succeeded, failed.
        #[arg(long)]
        state: Vec<String>,
    },
    /// Show one job.
    Get {
        /// Job id.
        id: String,
    },
    /// Print a job's iterations as they finish, then its result; exits 1 if it failed.
    Watch {
        /// Job id.
        id: String,
    },
    /// Stop a job gracefully (it checkpoints and ends STOPPED).
    Stop {
        /// Job id.
        id: String,
    },
    /// Continue a STOPPED or FAILED job from its last checkpoint.
    Resume {
        /// Job id.
        id: String,
        /// Then watch it until it ends.
        #[arg(long)]
        watch: bool,
    },
}

#[derive(Subcommand)]
enum DemosCmd {
    /// Generate an imbalanced, partly labeled dataset (safetensors).
    Generate {
        #[command(flatten)]
        config: ConfigArgs,
        /// Output file.
        #[arg(long, default_value = "demos.safetensors")]
        out: PathBuf,
    },
    /// Print a dataset's metadata (validating the whole file).
    Inspect {
        /// The dataset file.
        path: PathBuf,
    },
}

/// An error caused by the user's input (exit code 2).
#[derive(Debug)]
struct InputError(String);
impl std::fmt::Display for InputError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for InputError {}

fn input_err(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow::Error::new(InputError(e.to_string()))
}

/// `e` as an input error (exit 2) when it is a `T`, the library's typed input errors.
fn input_if<T: std::error::Error + Send + Sync + 'static>(e: anyhow::Error) -> anyhow::Error {
    if e.downcast_ref::<T>().is_some() {
        input_err(format!("{e:#}"))
    } else {
        e
    }
}

impl ConfigArgs {
    /// The layers these flags name (reading the config file).
    fn layers(&self) -> Result<ConfigLayers> {
        let config = self
            .config
            .as_ref()
            .map(|f| {
                std::fs::read_to_string(f)
                    .map(|text| (f.display().to_string(), text))
                    .map_err(|e| input_err(format!("cannot read config file {}: {e}", f.display())))
            })
            .transpose()?;
        Ok(ConfigLayers {
            preset: self.preset.clone(),
            preset_files: true,
            config,
            set: self.set.clone(),
            env: self.env.clone(),
            seed: self.seed,
        })
    }
}

fn resolve(args: &ConfigArgs) -> Result<CheckedConfig> {
    args.layers()?.resolve().map_err(input_err)
}

struct CliProgress {
    bar: Option<indicatif::ProgressBar>,
    total: usize,
    every: usize,
    last_eval: String,
}

impl CliProgress {
    fn new(total: usize) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = indicatif::ProgressBar::new(total as u64);
            b.set_style(
                indicatif::ProgressStyle::with_template(
                    "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} it  {msg}",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b
        });
        Self {
            bar,
            total,
            every: (total / 20).max(1),
            last_eval: String::new(),
        }
    }
}

impl Progress for CliProgress {
    fn iteration(&mut self, it: &IterationLog) {
        let sps = it.env_steps as f64 / it.wall_s.max(1e-9);
        if let (Some(n), Some(e), Some(r)) = (it.nmi, it.ent, it.normalized_reward) {
            self.last_eval = format!("  NMI {n:.3} ENT {e:.3} norm.reward {r:.2}");
        }
        let msg = format!(
            "{:.0} steps/s  D(exp) {:.2} D(pol) {:.2}  reward {:+.3}{}",
            sps, it.d_acc_expert, it.d_acc_policy, it.reward_mean, self.last_eval
        );
        match &self.bar {
            Some(b) => {
                b.set_position(it.iteration as u64);
                b.set_message(msg);
            }
            None => {
                if it.iteration.is_multiple_of(self.every)
                    || it.iteration == self.total
                    || it.nmi.is_some()
                {
                    eprintln!(
                        "iter {:>4}/{}  {:>8} steps  {:6.1}s  {msg}",
                        it.iteration, self.total, it.env_steps, it.wall_s
                    );
                }
            }
        }
    }

    fn message(&mut self, msg: &str) {
        match &self.bar {
            Some(b) => b.set_message(msg.to_string()),
            None => eprintln!("ess: {msg}"),
        }
    }
}

fn train(mut args: TrainArgs) -> Result<()> {
    match args.actors {
        Some(0) => {
            args.config.set.push("run.actors=1".into());
            args.config.set.push("run.transport=\"threads\"".into());
        }
        Some(n) => {
            args.config.set.push(format!("run.actors={n}"));
            args.config.set.push("run.transport=\"processes\"".into());
        }
        None => {}
    }
    let cfg = match &args.resume {
        Some(dir) => ess_learner::train::run_config(dir)
            .map_err(|e| input_err(format!("--resume: {e:#}")))?,
        None => resolve(&args.config)?,
    };
    if let Some(dir) = &args.resume
        && ess_learner::checkpoint::latest(&dir.join("checkpoints"))
            .map_err(input_err)?
            .is_none()
    {
        return Err(input_err(format!(
            "--resume: no complete checkpoint under {}",
            dir.join("checkpoints").display()
        )));
    }
    if args.print_config {
        print!("{}", cfg.to_toml());
        return Ok(());
    }
    if cfg.run.transport == ess_proto::config::ActorTransport::Processes {
        ess_learner::actors::actor_binary().map_err(input_err)?;
    }
    let out = args.resume.clone().or(args.out).unwrap_or_else(|| {
        PathBuf::from(format!(
            "runs/{}-{}-s{}",
            cfg.method.name, cfg.env.name, cfg.run.seed
        ))
    });
    let shutdown = ctrl_c_flag()?;
    eprintln!(
        "ess: {} {} on {} (seed {}, {} iterations x {} steps) -> {}",
        if args.resume.is_some() {
            "resuming"
        } else {
            "training"
        },
        cfg.method.name,
        cfg.env.name,
        cfg.run.seed,
        cfg.run.iterations,
        cfg.run.rollout_steps,
        out.display()
    );
    if args.progress == ProgressFormat::Jsonl {
        let mut progress =
            JsonlProgress::new(std::io::stdout().lock()).stop_when_reader_gone(shutdown.clone());
        let result = match args.resume {
            Some(_) => ess_learner::train::resume(&out, &mut progress, &shutdown),
            None => run(&cfg, &out, &mut progress, &shutdown),
        }
        .map_err(input_if::<ess_learner::train::TrainInputError>)?;
        progress.emit(&ProgressEvent::Summary((&result.summary).into()));
        return Ok(());
    }
    let mut progress = CliProgress::new(cfg.run.iterations);
    let result = match args.resume {
        Some(_) => ess_learner::train::resume(&out, &mut progress, &shutdown),
        None => run(&cfg, &out, &mut progress, &shutdown),
    }
    .map_err(input_if::<ess_learner::train::TrainInputError>)?;
    if let Some(b) = &progress.bar {
        b.finish_and_clear();
    }
    let s = &result.summary;
    println!("method             {}", s.method);
    println!("env                {} (seed {})", s.env, s.seed);
    // The paper's Table 1 value for this env and method, where it has one.
    let paper = ess_learner::presets::paper_table1(&s.env, &s.method)
        .map(|(n, e)| {
            (
                format!("; paper Table 1: {n:.3}"),
                format!("; paper: {e:.3}"),
            )
        })
        .unwrap_or_default();
    println!(
        "NMI                {:.3}   (higher is better{})",
        s.nmi, paper.0
    );
    println!(
        "ENT                {:.3}   (lower is better{})",
        s.ent, paper.1
    );
    println!(
        "normalized reward  {:.3}   (random 0, expert 1)",
        s.normalized_reward
    );
    println!(
        "p(c)               {}",
        s.prior
            .iter()
            .map(|p| format!("{p:.3}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!(
        "Q_c accuracy       {:.3} balanced, {:.3} overall on the unlabeled demos (per mode {})",
        s.encoder_accuracy.balanced,
        s.encoder_accuracy.overall,
        s.encoder_accuracy
            .per_mode
            .iter()
            .map(|p| format!("{p:.2}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!(
        "training           {} iterations, {} env steps, {:.1} s ({:.0} env steps/s); total {:.1} s",
        s.iterations, s.env_steps, s.wall_seconds, s.env_steps_per_second, s.total_seconds
    );
    println!(
        "per iteration      rollout {:.3} s, D/Q {:.3} s, PPO {:.3} s",
        s.seconds_per_iteration.rollout, s.seconds_per_iteration.disc, s.seconds_per_iteration.ppo
    );
    let traj = if s.env == "traj2d" {
        "trajectories.png,"
    } else {
        ""
    };
    println!(
        "outputs            {}/{{summary.json,metrics.csv,config.toml,run.mcap,{traj}curves.png,checkpoints/}}",
        out.display()
    );
    Ok(())
}

/// A flag set by the first Ctrl-C or SIGTERM (finish the iteration, save, stop actor
/// processes); a second exits.
fn ctrl_c_flag() -> Result<Arc<AtomicBool>> {
    let shutdown = Arc::new(AtomicBool::new(false));
    let flag = shutdown.clone();
    ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        eprintln!("ess: stopping after this iteration (Ctrl-C again to abort)");
    })
    .context("installing the Ctrl-C handler")?;
    Ok(shutdown)
}

fn experts(cmd: ExpertsCmd) -> Result<()> {
    match cmd {
        ExpertsCmd::Train {
            config,
            mode,
            steps,
            out,
            resume,
            init_from,
            algo,
        } => {
            let cfg = resolve(&config)?;
            if algo == ExpertAlgo::Sac && init_from.is_some() {
                // Before the --init-from file checks, which would miss the point.
                return Err(input_err(ess_learner::sac::SacInputError::InitFrom));
            }
            // SAC steps its one env in this process; PPO's actors may be processes.
            if algo == ExpertAlgo::Ppo
                && cfg.run.transport == ess_proto::config::ActorTransport::Processes
            {
                ess_learner::actors::actor_binary().map_err(input_err)?;
            }
            if mode >= cfg.env.n_modes {
                return Err(input_err(format!(
                    "--mode {mode} is out of range: env {} has {} modes (0..{})",
                    cfg.env.name,
                    cfg.env.n_modes,
                    cfg.env.n_modes - 1
                )));
            }
            let out = out.unwrap_or_else(|| {
                ess_envs::expert_path(&ess_envs::experts_dir(), &cfg.env.name, mode)
            });
            if resume && !out.exists() {
                return Err(input_err(format!(
                    "--resume: no expert file at {}",
                    out.display()
                )));
            }
            if let Some(src) = &init_from {
                let state = ess_learner::experts::state_path(src);
                for (what, p) in [("expert file", src), ("state file", &state)] {
                    if !p.exists() {
                        return Err(input_err(format!(
                            "--init-from: no {what} at {}",
                            p.display()
                        )));
                    }
                }
                let fits = || -> Result<()> {
                    let e = ess_envs::ExpertPolicy::load(src)?;
                    let env = ess_envs::make_plain_env(&cfg.env.name, cfg.env.n_modes)?;
                    e.check_fits(env.spec(), e.meta.mode, src)?;
                    Ok(())
                };
                fits().map_err(|e| input_err(format!("--init-from: {e:#}")))?;
                if src == &out {
                    return Err(input_err(format!(
                        "--init-from {} is the --out file; use --resume to continue it",
                        src.display()
                    )));
                }
            }
            let tc = ExpertTrainConfig {
                env: cfg.env.name.clone(),
                n_modes: cfg.env.n_modes,
                mode,
                steps,
                rollout_steps: cfg.run.rollout_steps,
                actors: cfg.run.actors,
                transport: cfg.run.transport,
                actor_timeout_s: cfg.run.actor_timeout_s,
                torch_threads: cfg.run.torch_threads.max(1),
                seed: cfg.run.seed,
                ppo: cfg.ppo.clone(),
                out: out.clone(),
                resume,
                init_from: init_from.clone(),
            };
            let shutdown = ctrl_c_flag()?;
            eprintln!(
                "ess: training the {} mode-{mode} expert for {steps} steps -> {}",
                tc.env,
                out.display()
            );
            let t0 = std::time::Instant::now();
            let mut last = 0.0;
            let mut report = |it: &ess_learner::experts::ExpertIteration| {
                let now = t0.elapsed().as_secs_f64();
                if now - last >= 5.0 || it.env_steps >= steps {
                    last = now;
                    eprintln!(
                        "iter {:5} {:9} steps {:7.1}s  return {:>10}  length {:>6}  entropy {:.3}",
                        it.iteration,
                        it.env_steps,
                        now,
                        it.mean_return
                            .map(|v| format!("{v:.2}"))
                            .unwrap_or_default(),
                        it.mean_length
                            .map(|v| format!("{v:.0}"))
                            .unwrap_or_default(),
                        it.entropy
                    );
                }
            };
            let e = match algo {
                ExpertAlgo::Ppo => train_expert(&tc, &mut report, &shutdown)?,
                ExpertAlgo::Sac => {
                    ess_learner::sac::train_expert_sac(&tc, &cfg.sac, &mut report, &shutdown)
                        .map_err(input_if::<ess_learner::sac::SacInputError>)?
                }
            };
            println!(
                "expert {} mode {}: {} steps, mean return of the last episodes {:.3} -> {}",
                e.meta.env,
                e.meta.mode,
                e.meta.trained_steps,
                e.meta.mean_return,
                out.display()
            );
        }
        ExpertsCmd::Eval {
            config,
            dir,
            episodes,
            json,
        } => {
            let cfg = resolve(&config)?;
            let dir = dir.unwrap_or_else(ess_envs::experts_dir);
            let plain =
                ess_envs::make_plain_env(&cfg.env.name, cfg.env.n_modes).map_err(input_err)?;
            let env = ess_envs::ExpertEnv::load(plain, &dir).map_err(input_err)?;
            let experts = env.experts().to_vec();
            let mut plain =
                ess_envs::make_plain_env(&cfg.env.name, cfg.env.n_modes).map_err(input_err)?;
            let rows = eval_experts(plain.as_mut(), &experts, episodes, cfg.run.seed)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&rows)?);
            } else {
                println!(
                    "| {} mode | expert return | random return | expert ep. length | fwd vel. expert | fwd vel. random | trained steps |",
                    cfg.env.name
                );
                println!("|---|---|---|---|---|---|---|");
                let v = |x: Option<f64>| x.map(|v| format!("{v:+.2} m/s")).unwrap_or("-".into());
                for (r, e) in rows.iter().zip(&experts) {
                    println!(
                        "| {} | {:.2} | {:.2} | {:.0} | {} | {} | {} |",
                        r.mode,
                        r.expert_return,
                        r.random_return,
                        r.expert_length,
                        v(r.forward_velocity),
                        v(r.random_forward_velocity),
                        e.meta.trained_steps
                    );
                }
            }
        }
    }
    Ok(())
}

fn demos(cmd: DemosCmd) -> Result<()> {
    match cmd {
        DemosCmd::Generate { config, out } => {
            let cfg = resolve(&config)?;
            let d = generate_demos(&demo_spec(&cfg)).map_err(input_err)?;
            d.save(&out)?;
            println!("wrote {}", out.display());
            println!("{}", serde_json::to_string_pretty(&d.meta)?);
        }
        DemosCmd::Inspect { path } => {
            let d = ess_envs::Demos::load(&path).map_err(input_err)?;
            println!("{}", serde_json::to_string_pretty(&d.meta)?);
        }
    }
    Ok(())
}

fn replay(a: ReplayArgs) -> Result<()> {
    use ess_learner::replay::{ReplayError, list, load, plot, replay};
    let input = |e: ReplayError| match e {
        ReplayError::Plot(_) => anyhow::Error::new(e),
        e => input_err(e),
    };
    if a.tol.is_nan() || a.tol < 0.0 {
        return Err(input_err(format!("--tol {} must be >= 0", a.tol)));
    }
    let rec = load(&a.file).map_err(input)?;
    if let Some(why) = &rec.truncated {
        eprintln!(
            "ess: {} is truncated or damaged ({why}); using its complete messages",
            a.file.display()
        );
    }
    let Some(episode) = a.episode else {
        if a.plot.is_some() {
            return Err(input_err("--plot needs --episode N"));
        }
        let rows = list(&rec);
        if a.json {
            println!("{}", serde_json::to_string_pretty(&rows)?);
        } else {
            println!(
                "{}: {} on {} (seed {}), {} evaluation episodes",
                a.file.display(),
                rec.config.method,
                rec.config.env,
                rec.config.seed,
                rows.len()
            );
            println!("episode  iteration  final  code     eps  length  return per mode");
            for r in &rows {
                let len = if r.recorded_steps == r.length as usize {
                    r.length.to_string()
                } else {
                    format!("{}/{}", r.recorded_steps, r.length)
                };
                println!(
                    "{:>7}  {:>9}  {:>5}  {:>4}  {:>+6.3}  {:>6}  {}",
                    r.episode,
                    r.iteration,
                    if r.final_eval { "yes" } else { "no" },
                    r.code,
                    r.eps,
                    len,
                    r.mode_returns
                        .iter()
                        .map(|v| format!("{v:.3}"))
                        .collect::<Vec<_>>()
                        .join(" ")
                );
            }
        }
        return Ok(());
    };
    let (report, traj) = replay(&rec, episode).map_err(input)?;
    let plots = match &a.plot {
        Some(out) => {
            plot(out, &traj, &format!("{} episode {episode}", rec.config.env)).map_err(input)?
        }
        None => Vec::new(),
    };
    let ok = report.max_deviation() <= a.tol;
    if a.json {
        let mut v = serde_json::to_value(&report)?;
        v["tol"] = serde_json::json!(a.tol);
        v["within_tol"] = serde_json::json!(ok);
        v["plots"] = serde_json::json!(plots);
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "episode {episode} of {} ({}): {} steps re-simulated",
            a.file.display(),
            report.env,
            report.steps
        );
        println!(
            "max |state - recorded|     {:.3e} (step {})",
            report.max_state_deviation, report.max_state_deviation_step
        );
        println!(
            "max |obs - recorded|       {:.3e}",
            report.max_obs_deviation
        );
        println!(
            "max |reward - recorded|    {:.3e}",
            report.max_reward_deviation
        );
        println!("reset(seed) vs start state {:.3e}", report.reset_deviation);
        for p in &plots {
            println!("plot                       {}", p.display());
        }
    }
    if !ok {
        anyhow::bail!(
            "episode {episode} of {}: replay deviates by {:.3e} from the recording, more than --tol {:e}",
            a.file.display(),
            report.max_deviation(),
            a.tol
        );
    }
    Ok(())
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")
}

/// Resolves on the first Ctrl-C or SIGTERM.
async fn shutdown_signal() {
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(e) => {
                tracing::warn!(error = %e, "cannot listen for SIGTERM");
                std::future::pending::<()>().await;
            }
        }
    };
    tokio::select! {
        r = tokio::signal::ctrl_c() => {
            if let Err(e) = r {
                tracing::warn!(error = %e, "cannot listen for Ctrl-C");
                std::future::pending::<()>().await;
            }
        }
        () = term => {}
    }
    eprintln!("ess serve: stopping running jobs (they checkpoint), then exiting");
}

async fn serve(a: ServeArgs) -> Result<()> {
    use ess_learner::jobs::ManagerConfig;
    use ess_learner::serve::ServeConfig;
    let addr: std::net::SocketAddr = a.listen.parse().map_err(|e| {
        input_err(format!(
            "--listen `{}`: expected IP:PORT (e.g. 127.0.0.1:50551): {e}",
            a.listen
        ))
    })?;
    let token = a
        .token_file
        .as_deref()
        .map(ess_learner::client::read_token_file)
        .transpose()
        .map_err(input_err)?;
    if !addr.ip().is_loopback() {
        if token.is_none() {
            return Err(input_err(format!(
                "--listen {addr} is reachable from other machines: give --token-file so that only token holders control jobs"
            )));
        }
        eprintln!(
            "ess serve: WARNING: listening on {addr} without TLS: the token and job data cross the network in plain text"
        );
    }
    let cores = match a.cores {
        Some(0) => return Err(input_err("--cores must be at least 1")),
        Some(n) => n,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    if !(a.stop_grace_s.is_finite() && a.stop_grace_s >= 0.0) {
        return Err(input_err(format!(
            "--stop-grace-s {} must be a number of seconds >= 0",
            a.stop_grace_s
        )));
    }
    let exe = std::env::current_exe().context("locating the ess binary to run jobs with")?;
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .with_context(|| format!("cannot listen on {addr}"))?;
    let bound = listener.local_addr().context("reading the bound address")?;
    {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        writeln!(out, "listening on {bound}")?;
        out.flush()?;
    }
    eprintln!(
        "ess serve: {} cores for jobs, data in {}, {}",
        cores,
        a.data_dir.display(),
        if token.is_some() {
            "bearer token required"
        } else {
            "no token (loopback only)"
        }
    );
    let cfg = ServeConfig {
        manager: ManagerConfig {
            data_dir: a.data_dir,
            cores,
            exe,
            stop_grace: std::time::Duration::from_secs_f64(a.stop_grace_s),
        },
        token,
    };
    ess_learner::serve::serve(listener, cfg, shutdown_signal()).await
}

/// A failed call as an error: the caller's fault (exit 2) or the server's (exit 1).
fn status_err(s: tonic::Status) -> anyhow::Error {
    use tonic::Code;
    let msg = format!("{:?}: {}", s.code(), s.message());
    match s.code() {
        Code::InvalidArgument
        | Code::NotFound
        | Code::FailedPrecondition
        | Code::Unauthenticated
        | Code::PermissionDenied => input_err(msg),
        _ => anyhow::anyhow!(msg),
    }
}

fn parse_state(s: &str) -> Result<ess_proto::pb::JobState> {
    use ess_proto::pb::JobState;
    Ok(match s.to_ascii_lowercase().as_str() {
        "queued" => JobState::Queued,
        "running" => JobState::Running,
        "stopping" => JobState::Stopping,
        "stopped" => JobState::Stopped,
        "succeeded" => JobState::Succeeded,
        "failed" => JobState::Failed,
        _ => {
            return Err(input_err(format!(
                "--state `{s}`: expected queued, running, stopping, stopped, succeeded or failed"
            )));
        }
    })
}

async fn job(a: JobArgs) -> Result<()> {
    use ess_learner::client::{self, event_json, job_detail, job_json, job_line};
    use ess_proto::pb;
    let server = a
        .server
        .or_else(|| std::env::var("ESS_SERVER").ok())
        .unwrap_or_else(|| format!("http://{}", ess_learner::serve::DEFAULT_LISTEN));
    let token_file = a
        .token_file
        .or_else(|| std::env::var_os("ESS_TOKEN_FILE").map(PathBuf::from));
    let token = token_file
        .as_deref()
        .map(client::read_token_file)
        .transpose()
        .map_err(input_err)?;
    let json = a.json;
    let print_job = |j: &pb::Job| {
        if json {
            println!("{}", job_json(j));
        } else {
            print!("{}", job_detail(j));
        }
    };
    // Validate local input before connecting.
    let spec = match &a.cmd {
        JobCmd::Submit { config, .. } => Some(job_spec(config)?),
        _ => None,
    };
    let mut c = client::connect(&server, token.as_deref()).await?;
    let watch_id = match a.cmd {
        JobCmd::Submit { watch, .. } => {
            let j = c
                .submit_job(pb::SubmitJobRequest { spec })
                .await
                .map_err(status_err)?
                .into_inner();
            if !watch || !json {
                print_job(&j);
            }
            watch.then_some(j.id)
        }
        JobCmd::List { state } => {
            let states = state
                .iter()
                .map(|s| parse_state(s).map(i32::from))
                .collect::<Result<Vec<_>>>()?;
            let jobs = c
                .list_jobs(pb::ListJobsRequest { states })
                .await
                .map_err(status_err)?
                .into_inner()
                .jobs;
            if json {
                println!(
                    "{}",
                    serde_json::Value::Array(jobs.iter().map(job_json).collect())
                );
            } else if jobs.is_empty() {
                println!("no jobs");
            } else {
                for j in &jobs {
                    println!("{}", job_line(j));
                }
            }
            None
        }
        JobCmd::Get { id } => {
            let j = c
                .get_job(pb::GetJobRequest { id })
                .await
                .map_err(status_err)?
                .into_inner();
            print_job(&j);
            None
        }
        JobCmd::Stop { id } => {
            let j = c
                .stop_job(pb::StopJobRequest { id })
                .await
                .map_err(status_err)?
                .into_inner();
            print_job(&j);
            None
        }
        JobCmd::Resume { id, watch } => {
            let j = c
                .resume_job(pb::ResumeJobRequest { id })
                .await
                .map_err(status_err)?
                .into_inner();
            if !watch || !json {
                print_job(&j);
            }
            watch.then_some(j.id)
        }
        JobCmd::Watch { id } => Some(id),
    };
    let Some(id) = watch_id else {
        return Ok(());
    };
    let mut stream = c
        .watch_job(pb::WatchJobRequest { id: id.clone() })
        .await
        .map_err(status_err)?
        .into_inner();
    let mut last: Option<pb::Job> = None;
    while let Some(ev) = stream.message().await.map_err(status_err)? {
        if json {
            println!("{}", event_json(&ev));
        } else if let Some(m) = &ev.metrics {
            let total = ev.job.as_ref().map_or(0, |j| j.iterations);
            println!("{}", client::iteration_line(m, total));
        } else if let Some(j) = &ev.job {
            let changed = last
                .as_ref()
                .is_none_or(|l| l.state != j.state || l.phase != j.phase);
            if changed {
                let phase = if j.phase.is_empty() {
                    String::new()
                } else {
                    format!(" ({})", j.phase)
                };
                println!("{} {}{phase}", j.id, client::state_name(j.state));
            }
        }
        if let Some(j) = ev.job {
            last = Some(j);
        }
    }
    let Some(j) = last else {
        anyhow::bail!("the server ended the watch of {id} without an event");
    };
    if !json {
        print!("{}", job_detail(&j));
    }
    match pb::JobState::try_from(j.state) {
        Ok(pb::JobState::Failed) => Err(anyhow::anyhow!("job {} failed: {}", j.id, j.error)),
        Ok(pb::JobState::Stopped | pb::JobState::Succeeded) => Ok(()),
        _ => Err(anyhow::anyhow!(
            "the watch of {} ended while the job is {}",
            j.id,
            client::state_name(j.state)
        )),
    }
}

/// The job spec the config flags describe (the config file's contents travel).
fn job_spec(c: &ConfigArgs) -> Result<ess_proto::pb::JobSpec> {
    use ess_proto::pb;
    if c.preset.ends_with(".toml") || c.preset.contains('/') {
        return Err(input_err(format!(
            "--preset {}: a job takes a preset name (`ess presets`); pass a file with --config",
            c.preset
        )));
    }
    let config_toml = match &c.config {
        Some(f) => std::fs::read_to_string(f)
            .map_err(|e| input_err(format!("cannot read config file {}: {e}", f.display())))?,
        None => String::new(),
    };
    let overrides = c
        .set
        .iter()
        .map(|s| {
            s.split_once('=')
                .map(|(k, v)| pb::Override {
                    key: k.trim().to_string(),
                    value: v.trim().to_string(),
                })
                .ok_or_else(|| input_err(format!("--set `{s}`: expected KEY=VALUE")))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(pb::JobSpec {
        preset: c.preset.clone(),
        env: c.env.clone().unwrap_or_default(),
        seed: c.seed,
        overrides,
        config_toml,
    })
}

fn main() {
    ess_learner::malloc::keep_freed_memory();
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .init();
    let cli = Cli::parse();
    let r = match cli.cmd {
        Cmd::Train(a) => train(a),
        Cmd::Demos { cmd } => demos(cmd),
        Cmd::Experts { cmd } => experts(cmd),
        Cmd::Replay(a) => replay(a),
        Cmd::Serve(a) => runtime().and_then(|rt| rt.block_on(serve(a))),
        Cmd::Job(a) => runtime().and_then(|rt| rt.block_on(job(a))),
        Cmd::Report { runs } => runs
            .iter()
            .map(|d| ess_learner::table::read_run(d).map_err(input_err))
            .collect::<Result<Vec<_>>>()
            .map(|rows| print!("{}", ess_learner::table::markdown(&rows))),
        Cmd::Presets => {
            for (name, text) in PRESETS {
                let doc = text
                    .lines()
                    .next()
                    .unwrap_or("")
                    .trim_start_matches('#')
                    .trim();
                println!("{name:22} {doc}");
            }
            Ok(())
        }
    };
    if let Err(e) = r {
        eprintln!("error: {e:#}");
        let code = if e.downcast_ref::<InputError>().is_some() {
            2
        } else {
            1
        };
        std::process::exit(code);
    }
}
