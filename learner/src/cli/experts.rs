//! `ess experts`: per-mode expert policies (PPO or SAC on each mode's task reward).

use super::{ConfigArgs, ctrl_c_flag, input_err, input_if, input_if_corrupt, resolve};
use anyhow::Result;
use clap::Subcommand;
use ess_learner::experts::{ExpertTrainConfig, eval_experts, train_expert};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum ExpertsCmd {
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
pub enum ExpertAlgo {
    /// PPO with GAE, the imitation learner's ([`ess_learner::train::ppo`]).
    Ppo,
    /// Soft actor-critic ([`ess_learner::experts::sac`]).
    Sac,
}

pub fn experts(cmd: ExpertsCmd) -> Result<()> {
    match cmd {
        ExpertsCmd::Train {
            config,
            mode,
            steps,
            out,
            resume,
            init_from,
            algo,
        } => train(&config, mode, steps, out, resume, init_from, algo),
        ExpertsCmd::Eval {
            config,
            dir,
            episodes,
            json,
        } => eval(&config, dir, episodes, json),
    }
}

/// `ess experts train`.
fn train(
    config: &ConfigArgs,
    mode: usize,
    steps: u64,
    out: Option<PathBuf>,
    resume: bool,
    init_from: Option<PathBuf>,
    algo: ExpertAlgo,
) -> Result<()> {
    let cfg = resolve(config)?;
    if algo == ExpertAlgo::Sac && init_from.is_some() {
        // Before the --init-from file checks, which would miss the point.
        return Err(input_err(
            ess_learner::experts::sac::SacInputError::InitFrom,
        ));
    }
    // SAC steps its one env in this process; PPO's actors may be processes.
    if algo == ExpertAlgo::Ppo && cfg.run.transport == ess_proto::config::ActorTransport::Processes
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
    let out =
        out.unwrap_or_else(|| ess_envs::expert_path(&ess_envs::experts_dir(), &cfg.env.name, mode));
    if resume && !out.exists() {
        return Err(input_err(format!(
            "--resume: no expert file at {}",
            out.display()
        )));
    }
    if let Some(src) = &init_from {
        check_init_from(&cfg, src, &out)?;
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
        ExpertAlgo::Ppo => train_expert(&tc, &mut report, &shutdown)
            .map_err(input_if::<ess_envs::ExpertError>)
            .map_err(input_if_corrupt)?,
        ExpertAlgo::Sac => {
            ess_learner::experts::sac::train_expert_sac(&tc, &cfg.sac, &mut report, &shutdown)
                .map_err(input_if::<ess_learner::experts::sac::SacInputError>)
                .map_err(input_if::<ess_envs::ExpertError>)
                .map_err(input_if_corrupt)?
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
    Ok(())
}

/// `--init-from SRC`: the expert and its state file exist, fit the env, and are not
/// the `--out` file.
fn check_init_from(
    cfg: &ess_proto::CheckedConfig,
    src: &std::path::Path,
    out: &std::path::Path,
) -> Result<()> {
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
    if src == out {
        return Err(input_err(format!(
            "--init-from {} is the --out file; use --resume to continue it",
            src.display()
        )));
    }
    Ok(())
}

/// `ess experts eval`.
fn eval(config: &ConfigArgs, dir: Option<PathBuf>, episodes: usize, json: bool) -> Result<()> {
    let cfg = resolve(config)?;
    let dir = dir.unwrap_or_else(ess_envs::experts_dir);
    let plain = ess_envs::make_plain_env(&cfg.env.name, cfg.env.n_modes).map_err(input_err)?;
    let env = ess_envs::ExpertEnv::load(plain, &dir).map_err(input_err)?;
    let experts = env.experts().to_vec();
    let mut plain = ess_envs::make_plain_env(&cfg.env.name, cfg.env.n_modes).map_err(input_err)?;
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
    Ok(())
}
