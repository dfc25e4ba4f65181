//! `ess train`: one training run, with a progress bar, lines or a JSONL stream.

use super::{ConfigArgs, ctrl_c_flag, input_err, input_if, input_if_corrupt, resolve};
use anyhow::Result;
use clap::Args;
use ess_learner::logs;
use ess_learner::progress::{JsonlProgress, ProgressEvent};
use ess_learner::train::{IterationLog, Progress, run};
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(Args)]
pub struct TrainArgs {
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
    /// one actor as a thread of this process instead (run.actors=0, checked into
    /// run.actors=1, run.transport="threads"): the single-process path.
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
    /// The learner's implementation: `fused` (the default) or `tch` (sets
    /// learner.backend); with --resume, the backend the run continues on (a checkpoint
    /// of either resumes on the other).
    #[arg(long, value_enum)]
    backend: Option<BackendArg>,
    /// How progress is reported: `human` (a bar or lines on stderr, a summary on
    /// stdout) or `jsonl` (one JSON object per line on stdout: messages, every
    /// iteration's metrics, the final result; what `ess serve` reads).
    #[arg(long, value_enum, default_value = "human")]
    progress: ProgressFormat,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendArg {
    Fused,
    Tch,
}

impl From<BackendArg> for ess_learner::train::Backend {
    fn from(b: BackendArg) -> Self {
        match b {
            BackendArg::Fused => Self::Fused,
            BackendArg::Tch => Self::Tch,
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ProgressFormat {
    Human,
    Jsonl,
}

pub struct CliProgress {
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

pub fn train(mut args: TrainArgs) -> Result<()> {
    match args.actors {
        // Config checking turns 0 into one actor thread (`run.actors` docs).
        Some(0) => args.config.set.push("run.actors=0".into()),
        Some(n) => {
            args.config.set.push(format!("run.actors={n}"));
            args.config.set.push("run.transport=\"processes\"".into());
        }
        None => {}
    }
    let backend = args.backend.map(ess_learner::train::Backend::from);
    let cfg = match &args.resume {
        Some(dir) => ess_learner::train::run_config(dir)
            .map_err(|e| input_err(format!("--resume: {e:#}")))?,
        None => resolve(&args.config)?,
    };
    let cfg = match backend {
        Some(b) => cfg.with_backend(b),
        None => cfg,
    };
    if let Some(dir) = &args.resume
        && ess_learner::train::checkpoint::latest(&dir.join("checkpoints"))
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
    ess_learner::remote::check_files(&cfg.remote).map_err(input_err)?;
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
            Some(_) => {
                ess_learner::train::resume_on(&out, backend, logs::open, &mut progress, &shutdown)
            }
            None => run(&cfg, &out, logs::open, &mut progress, &shutdown),
        }
        .map_err(input_if::<ess_learner::train::TrainInputError>)
        .map_err(input_if::<ess_envs::DemoError>)
        .map_err(input_if_corrupt)?;
        progress.emit(&ProgressEvent::Summary((&result.summary).into()));
        return Ok(());
    }
    let mut progress = CliProgress::new(cfg.run.iterations);
    let result = match args.resume {
        Some(_) => {
            ess_learner::train::resume_on(&out, backend, logs::open, &mut progress, &shutdown)
        }
        None => run(&cfg, &out, logs::open, &mut progress, &shutdown),
    }
    .map_err(input_if::<ess_learner::train::TrainInputError>)
    .map_err(input_if::<ess_envs::DemoError>)
    .map_err(input_if_corrupt)?;
    if let Some(b) = &progress.bar {
        b.finish_and_clear();
    }
    print_result(&result.summary, &out);
    Ok(())
}

/// The result block `ess train` prints on stdout.
fn print_result(s: &ess_learner::train::Summary, out: &std::path::Path) {
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
    let three = |v: &mut dyn Iterator<Item = f64>| {
        v.map(|p| format!("{p:.3}")).collect::<Vec<_>>().join(" ")
    };
    let demos = match s.prior_tv {
        Some(tv) => format!(
            "   (demos' modes {}: total variation {tv:.3})",
            three(&mut s.demo_mode_freq.iter().copied())
        ),
        None => String::new(),
    };
    println!(
        "p(c)               {}{demos}",
        three(&mut s.prior.iter().map(|&p| f64::from(p)))
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
        "outputs            {}/{{summary.json,metrics.csv,config.toml,run.mcap,{traj}curves.png,checkpoints/,tb/}}",
        out.display()
    );
}
