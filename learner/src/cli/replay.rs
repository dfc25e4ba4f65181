//! `ess replay`: a run log's evaluation episodes, listed or re-simulated.

use super::input_err;
use anyhow::Result;
use clap::Args;
use std::path::PathBuf;

#[derive(Args)]
pub struct ReplayArgs {
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
    /// Write the re-simulated episode's robot into this MCAP file (`/scene`, `/tf` in
    /// Foxglove's schemas, with the run's `/config`), for Foxglove or Lichtblick; needs
    /// --episode and an env with bodies (not traj2d).
    #[arg(long, value_name = "MCAP")]
    mcap: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

pub fn replay(a: ReplayArgs) -> Result<()> {
    use ess_learner::runlog::replay::{ReplayError, load, plot, replay};
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
        if a.plot.is_some() || a.mcap.is_some() {
            return Err(input_err("--plot and --mcap need --episode N"));
        }
        return print_list(&a, &rec);
    };
    let (report, traj) = replay(&rec, episode).map_err(input)?;
    let plots = match &a.plot {
        Some(out) => {
            plot(out, &traj, &format!("{} episode {episode}", rec.config.env)).map_err(input)?
        }
        None => Vec::new(),
    };
    if let Some(out) = &a.mcap {
        write_scene(out, &rec, episode, &traj).map_err(input)?;
    }
    let ok = report.max_deviation() <= a.tol;
    if a.json {
        let mut v = serde_json::to_value(&report)?;
        v["tol"] = serde_json::json!(a.tol);
        v["within_tol"] = serde_json::json!(ok);
        v["plots"] = serde_json::json!(plots);
        v["mcap"] = serde_json::json!(a.mcap);
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
        if let Some(m) = &a.mcap {
            println!("scene (Foxglove)           {}", m.display());
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

/// `--mcap OUT`: the replayed episode's robot as its own run log.
fn write_scene(
    out: &std::path::Path,
    rec: &ess_learner::runlog::replay::Recording,
    episode: u32,
    traj: &ess_learner::runlog::replay::Trajectory,
) -> Result<(), ess_learner::runlog::replay::ReplayError> {
    use ess_learner::runlog::replay::{ReplayError, episode_scene};
    let Some((scene, poses, code)) = episode_scene(rec, episode, traj)? else {
        return Err(ReplayError::Episode {
            path: rec.path.clone(),
            episode,
            why: format!("--mcap: env `{}` has no bodies to draw", traj.env),
        });
    };
    ess_learner::runlog::RunLog::write_scene_file(
        out,
        &rec.config,
        &scene,
        &poses,
        (episode, code),
    )?;
    Ok(())
}

/// Without `--episode`: one line per logged evaluation episode (or JSON).
fn print_list(a: &ReplayArgs, rec: &ess_learner::runlog::replay::Recording) -> Result<()> {
    use ess_learner::runlog::replay::list;
    let rows = list(rec);
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
    Ok(())
}
