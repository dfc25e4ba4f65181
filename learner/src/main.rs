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
use ess_learner::presets::{self, PRESETS, preset};
use ess_learner::train::{IterationLog, Progress, demo_spec, run};
use ess_proto::config::{CheckedConfig, ConfigBuilder};
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
    /// Table 1 view of finished runs: a row per run, mean ± std per env and method
    /// beside the paper's value (Markdown).
    Report {
        /// Run directories (each holding a summary.json).
        #[arg(required = true)]
        runs: Vec<PathBuf>,
    },
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
        #[arg(long)]
        resume: bool,
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
    /// run.actors=N, run.transport="processes"); 0 keeps the in-process threads.
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

fn resolve(args: &ConfigArgs) -> Result<CheckedConfig> {
    // First pass: learn which env the layers select; second pass: put that env's
    // defaults (mode count, label ratio) under the preset, the file and `--set`.
    let first = resolve_with(args, None)?;
    let cfg = match presets::env_defaults(&first.env.name) {
        Some(layer) => resolve_with(args, Some((&first.env.name, layer)))?,
        None => first,
    };
    ess_envs::make_plain_env(&cfg.env.name, cfg.env.n_modes).map_err(input_err)?;
    Ok(cfg)
}

fn resolve_with(args: &ConfigArgs, env_layer: Option<(&str, &str)>) -> Result<CheckedConfig> {
    let mut b = ConfigBuilder::new();
    let env_layer = env_layer
        .map(|(env, text)| presets::parse_env_layer(env, text))
        .transpose()
        .map_err(input_err)?;
    if let Some(layer) = &env_layer {
        b.merge_env_layer(layer).map_err(input_err)?;
    }
    let (name, text) = if args.preset.ends_with(".toml") || args.preset.contains('/') {
        let text = std::fs::read_to_string(&args.preset)
            .map_err(|e| input_err(format!("cannot read preset file {}: {e}", args.preset)))?;
        (args.preset.clone(), text)
    } else {
        (
            format!("preset {}", args.preset),
            preset(&args.preset).map_err(input_err)?.to_string(),
        )
    };
    b.merge_toml(&name, &text).map_err(input_err)?;
    if let Some(layer) = &env_layer {
        b.merge_env_method_layer(layer).map_err(input_err)?;
    }
    if let Some(f) = &args.config {
        let text = std::fs::read_to_string(f)
            .map_err(|e| input_err(format!("cannot read config file {}: {e}", f.display())))?;
        b.merge_toml(&f.display().to_string(), &text)
            .map_err(input_err)?;
    }
    for s in &args.set {
        b.set(s).map_err(input_err)?;
    }
    if let Some(env) = &args.env {
        b.set(&format!("env.name=\"{env}\"")).map_err(input_err)?;
    }
    if let Some(seed) = args.seed {
        b.set(&format!("run.seed={seed}")).map_err(input_err)?;
    }
    b.build().map_err(input_err)
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
        Some(0) => args.config.set.push("run.transport=\"threads\"".into()),
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
    let mut progress = CliProgress::new(cfg.run.iterations);
    let result = match args.resume {
        Some(_) => ess_learner::train::resume(&out, &mut progress, &shutdown)?,
        None => run(&cfg, &out, &mut progress, &shutdown)?,
    };
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
        "outputs            {}/{{summary.json,metrics.csv,config.toml,{traj}curves.png,checkpoints/}}",
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
        } => {
            let cfg = resolve(&config)?;
            if cfg.run.transport == ess_proto::config::ActorTransport::Processes {
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
            };
            let shutdown = ctrl_c_flag()?;
            eprintln!(
                "ess: training the {} mode-{mode} expert for {steps} steps -> {}",
                tc.env,
                out.display()
            );
            let t0 = std::time::Instant::now();
            let mut last = 0.0;
            let e = train_expert(
                &tc,
                &mut |it| {
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
                },
                &shutdown,
            )?;
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

fn main() {
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
