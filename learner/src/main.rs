//! `ess`: train imitation policies from multi-modal, imbalanced, mostly unlabeled
//! demonstrations (Ess-InfoGAIL and its baselines).
//!
//! Thin binary: parse, set up tracing, call the library. Data goes to stdout, logs and
//! progress to stderr. Exit codes: 0 ok, 1 runtime failure, 2 bad input (arguments,
//! configuration, files).

mod cli;

use anyhow::Result;
use clap::{Parser, Subcommand};
use cli::{
    InputError, demos::DemosCmd, experiment::ExperimentArgs, experts::ExpertsCmd,
    export::ExportArgs, input_err, job::JobArgs, replay::ReplayArgs, runtime, serve::ServeArgs,
    train::TrainArgs,
};
use ess_learner::presets::PRESETS;
use std::path::PathBuf;

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
    /// Run a grid of trainings (presets x tasks x variants x seeds) from a TOML spec
    /// here or on Slurm, and report it as the paper's tables and figures.
    Experiment(ExperimentArgs),
    /// Export a trained policy (`--onnx FILE`: a standard ONNX model).
    Export(ExportArgs),
    /// List the method presets.
    Presets,
    /// Run the job server: a gRPC daemon that owns training jobs on this machine.
    Serve(ServeArgs),
    /// Talk to a job server: submit, list, get, watch, stop, resume jobs.
    Job(JobArgs),
    /// Run this machine's actor processes for learners on other machines (their
    /// `[remote]` config), one run after another, over zenoh with mutual TLS.
    ActorHost(cli::actor_host::ActorHostArgs),
    /// Table 1 view of finished runs: a row per run, mean ± std per env and method
    /// beside the paper's value (Markdown); for Walker2d and Humanoid runs also each
    /// code's episode length, velocity and normalised reward beside its expert's, and
    /// `<run>/behaviours.png`.
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

impl Cmd {
    /// Commands whose work is their output: lists, reports, inspections, job queries.
    /// Not those that run trainings (`train`, `experts`, an experiment's cells) or
    /// serve: a job's `ess train` stops *gracefully* when its progress pipe to the server
    /// breaks, so it must see the write fail rather than die of SIGPIPE.
    fn only_prints(&self) -> bool {
        match self {
            Cmd::Presets | Cmd::Report { .. } | Cmd::Replay(_) | Cmd::Job(_) => true,
            Cmd::Demos { cmd } => matches!(cmd, DemosCmd::Inspect { .. }),
            Cmd::Export(_) => true,
            Cmd::Experiment(a) => a.only_prints(),
            Cmd::Train(_) | Cmd::Experts { .. } | Cmd::Serve(_) | Cmd::ActorHost(_) => false,
        }
    }
}

fn main() {
    ess_learner::malloc::keep_freed_memory();
    ess_actor::logging::init();
    let cli = Cli::parse();
    if cli.cmd.only_prints() {
        end_quietly_on_closed_stdout();
    }
    let r = match cli.cmd {
        Cmd::Train(a) => cli::train::train(a),
        Cmd::Demos { cmd } => cli::demos::demos(cmd),
        Cmd::Experts { cmd } => cli::experts::experts(cmd),
        Cmd::Replay(a) => cli::replay::replay(a),
        Cmd::Export(a) => cli::export::export(a),
        Cmd::Experiment(a) => cli::experiment::experiment(a),
        Cmd::ActorHost(a) => cli::actor_host::actor_host(a),
        Cmd::Serve(a) => runtime().and_then(|rt| rt.block_on(cli::serve::serve(a))),
        Cmd::Job(a) => runtime().and_then(|rt| rt.block_on(cli::job::job(a))),
        Cmd::Report { runs } => report(&runs),
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

/// Output piped into a reader that stops early (`ess experiment SPEC --list | head`) ends
/// the process quietly, as it does other Unix tools, instead of a panic in `println!`
/// (Rust ignores SIGPIPE, so the write fails and `println!` panics). Only for
/// [`Cmd::only_prints`]. Sockets are not affected: the standard library sends with
/// `MSG_NOSIGNAL`.
fn end_quietly_on_closed_stdout() {
    // SAFETY: sets one signal's disposition back to the default, before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// `ess report`: the Table 1 view, then each moving run's codes beside their experts
/// and each run's normalised reward per code at every evaluation.
fn report(runs: &[PathBuf]) -> Result<()> {
    use ess_learner::eval::table;
    let rows = runs
        .iter()
        .map(|d| table::read_run(d).map_err(input_err))
        .collect::<Result<Vec<_>>>()?;
    let curves = runs
        .iter()
        .map(|d| table::reward_curve_per_code(d).map_err(input_err))
        .collect::<Result<Vec<_>>>()?;
    print!("{}", table::markdown(&rows));
    for (row, curve) in rows.iter().zip(curves) {
        let section = ess_learner::runlog::behaviour::section;
        if let Some(md) = section(&row.dir, &row.reward_per_code, &row.assignment)? {
            print!("{md}");
        }
        if !curve.is_empty() {
            print!("{}", table::curve_markdown(&row.dir, &curve));
        }
    }
    Ok(())
}
