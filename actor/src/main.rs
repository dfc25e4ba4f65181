//! `ess-actor`: one actor process. The learner (`ess train --actors N`) starts N of these;
//! each steps its own environment with the policy the learner publishes and sends back
//! transition chunks over iceoryx2 shared memory (see `ess_actor::shm`).

use anyhow::{Context, Result};
use clap::Parser;
use ess_actor::Worker;
use ess_actor::shm::{ActorSettings, run_actor};

/// One Ess actor process (started by `ess train --actors N`, not by hand).
#[derive(Parser, Debug)]
#[command(name = "ess-actor", version)]
struct Args {
    /// Run id: names the run's iceoryx2 services.
    #[arg(long)]
    run_id: String,
    /// This actor's index, 0-based.
    #[arg(long)]
    index: usize,
    /// Number of actors in the run.
    #[arg(long)]
    n_actors: usize,
    /// Environment name (env.name).
    #[arg(long)]
    env: String,
    /// Behaviour modes of the environment (env.n_modes).
    #[arg(long)]
    n_modes: usize,
    /// Number of latent codes K.
    #[arg(long)]
    n_codes: usize,
    /// Seed of this actor's random stream.
    #[arg(long)]
    seed: u64,
    /// Most steps one request asks for (sizes the shared-memory chunks).
    #[arg(long)]
    max_steps: usize,
    /// Exit when this process is no longer our parent (the learner died).
    #[arg(long)]
    parent_pid: Option<u32>,
    /// Start from the state in this file (a checkpoint's, written by the learner when
    /// resuming; `ess_actor::state_msg`) instead of a fresh episode.
    #[arg(long, value_name = "FILE")]
    restore_state: Option<std::path::PathBuf>,
    /// Build the env without its scripted/trained expert (`ess experts train`).
    #[arg(long)]
    plain_env: bool,
    /// Record mode K's task reward as each step's env reward (`ess experts train`).
    #[arg(long, value_name = "K")]
    task_mode: Option<usize>,
}

fn main() -> Result<()> {
    ess_actor::logging::init();
    let a = Args::parse();
    if a.n_actors == 0 || a.index >= a.n_actors {
        anyhow::bail!(
            "--index {} must be below --n-actors {} (and --n-actors at least 1)",
            a.index,
            a.n_actors
        );
    }
    let build = |a: &Args| -> Result<Box<dyn ess_envs::Env>> {
        if a.plain_env {
            ess_envs::make_plain_env(&a.env, a.n_modes)
        } else {
            ess_envs::make_env(&a.env, a.n_modes).map(|e| e as Box<dyn ess_envs::Env>)
        }
        .with_context(|| format!("building env `{}` with {} modes", a.env, a.n_modes))
    };
    let env = build(&a)?;
    let mut worker = Worker::new(env, a.seed, a.n_codes);
    if let Some(k) = a.task_mode {
        worker = worker
            .with_task_reward(k)
            .with_context(|| format!("--task-mode {k}"))?;
    }
    if let Some(p) = &a.restore_state {
        restore(&mut worker, p, a.index)?;
    }
    let settings = ActorSettings {
        run_id: a.run_id.clone(),
        index: a.index,
        n_actors: a.n_actors,
        max_steps: a.max_steps,
        n_codes: a.n_codes,
        parent_pid: a.parent_pid,
    };
    // Evaluation episodes run on a second env of the same kind, built on first use.
    let mut eval_env = || build(&a).map_err(|e| format!("{e:#}"));
    run_actor(&settings, &mut worker, &mut eval_env)
        .with_context(|| format!("actor {} of run {}", a.index, a.run_id))
}

/// Restores `worker` from a state file the learner wrote for actor `index`.
fn restore(worker: &mut Worker, path: &std::path::Path, index: usize) -> Result<()> {
    let bytes =
        std::fs::read(path).with_context(|| format!("--restore-state {}", path.display()))?;
    if bytes.len() % 8 != 0 {
        anyhow::bail!(
            "--restore-state {}: {} bytes, not whole 8-byte words (cut?)",
            path.display(),
            bytes.len()
        );
    }
    let words: Vec<u64> = bytes
        .chunks_exact(8)
        .map(|c| u64::from_le_bytes(c.try_into().unwrap_or_default()))
        .collect();
    let m = ess_actor::state_msg::decode(&words)
        .with_context(|| format!("--restore-state {}", path.display()))?;
    if m.actor as usize != index {
        anyhow::bail!(
            "--restore-state {}: the state of actor {}, not of actor {index}",
            path.display(),
            m.actor
        );
    }
    worker
        .restore(&m.state)
        .with_context(|| format!("--restore-state {}", path.display()))
}
