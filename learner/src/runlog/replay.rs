//! `ess replay`: list the evaluation episodes of a run log ([`crate::runlog`]) and
//! re-simulate one from its recorded start state and actions.
//!
//! Re-simulation builds the env from the log's `/config` record (env name and mode
//! count, [`ess_envs::make_plain_env`]), restores the recorded start state
//! ([`ess_envs::Env::set_state`]), applies the recorded actions, and compares the env's
//! state, observation and mode rewards after every step with the recording. Envs step
//! deterministically, so on the machine and build that recorded the run the deviation
//! is 0; [`ReplayReport::max_state_deviation`] above a tolerance means the simulation
//! is not reproducible (a different MuJoCo build, a nondeterministic change, a
//! corrupted log).
//!
//! Plots ([`plot`]): Traj2D draws the x-y path; MuJoCo envs draw joint positions (the
//! `qpos` part of the state) over time, plus a body path in a second file
//! `<name>-path.png` (Reacher: fingertip; Pusher: fingertip and object; Walker2d: root
//! x-z; Humanoid: root x-y).

use crate::runlog::{Record, RunLogContents, RunLogError, read};
use ess_envs::{Env, EnvError, Pusher, PusherConfig, Reacher, ReacherConfig, make_training_env};
use ess_proto::pb;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Errors of `ess replay`; each names the file and, where it applies, the episode.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The log could not be read.
    #[error(transparent)]
    Log(#[from] RunLogError),
    /// The log has no `/config` record (so the env is unknown).
    #[error("{}: no /config record: not a run log of `ess train`, or cut before its first message", path.display())]
    NoConfig {
        /// The file.
        path: PathBuf,
    },
    /// No episode with that index.
    #[error("{}: no evaluation episode {episode}; the log holds {count} (indices {range})", path.display())]
    NoSuchEpisode {
        /// The file.
        path: PathBuf,
        /// The index asked for.
        episode: u32,
        /// Episodes in the log.
        count: usize,
        /// Their indices, as `a..=b` or `none`.
        range: String,
    },
    /// The episode cannot be re-simulated as recorded.
    #[error("{}: episode {episode}: {why}", path.display())]
    Episode {
        /// The file.
        path: PathBuf,
        /// The episode.
        episode: u32,
        /// What does not fit.
        why: String,
    },
    /// The env refused the recorded state or an action.
    #[error("{}: episode {episode}, {at}: {source}", path.display())]
    Env {
        /// The file.
        path: PathBuf,
        /// The episode.
        episode: u32,
        /// Where (`start state`, `step 12`, building env `x`).
        at: String,
        /// The env's error.
        #[source]
        source: EnvError,
    },
    /// Drawing the plot failed.
    #[error(transparent)]
    Plot(#[from] crate::eval::plot::PlotError),
}

/// A run log's evaluation episodes, each with its recorded steps.
#[derive(Debug, Clone)]
pub struct Recording {
    /// The file read.
    pub path: PathBuf,
    /// The run's configuration record.
    pub config: pb::RunConfig,
    /// Episodes in log order with their steps (fewer than `length` when the file was
    /// cut mid-episode).
    pub episodes: Vec<(pb::EvalEpisode, Vec<pb::EvalStep>)>,
    /// Why reading stopped early, for a truncated file.
    pub truncated: Option<String>,
}

/// One line of `ess replay FILE`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EpisodeInfo {
    /// Episode index (`--episode`).
    pub episode: u32,
    /// Training iteration of the evaluated policy.
    pub iteration: u32,
    /// Part of the final evaluation.
    pub final_eval: bool,
    /// Latent code index.
    pub code: u32,
    /// eps.
    pub eps: f32,
    /// Steps of the episode.
    pub length: u32,
    /// Steps present in the log (less than `length` in a truncated file).
    pub recorded_steps: usize,
    /// Return per behaviour mode.
    pub mode_returns: Vec<f64>,
}

/// What re-simulating one episode found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReplayReport {
    /// The log file.
    pub file: PathBuf,
    /// Episode index.
    pub episode: u32,
    /// Environment.
    pub env: String,
    /// Steps re-simulated.
    pub steps: usize,
    /// Largest `|state - recorded state|` over all steps and state components.
    pub max_state_deviation: f64,
    /// Step (0-based) where it occurred.
    pub max_state_deviation_step: usize,
    /// Largest `|obs - recorded next obs|`.
    pub max_obs_deviation: f64,
    /// Largest `|mode reward - recorded mode reward|`.
    pub max_reward_deviation: f64,
    /// Largest deviation of `reset(reset_seed)` from the recorded start state (a check
    /// of the reset; the replay itself starts from the recorded state).
    pub reset_deviation: f64,
}

impl ReplayReport {
    /// The largest of the state, observation and reward deviations.
    pub fn max_deviation(&self) -> f64 {
        self.max_state_deviation
            .max(self.max_obs_deviation)
            .max(self.max_reward_deviation)
    }
}

/// The recorded and re-simulated states of a replayed episode (for plots).
#[derive(Debug, Clone, Default)]
pub struct Trajectory {
    /// Environment name.
    pub env: String,
    /// Behaviour modes.
    pub n_modes: usize,
    /// Start state, then the recorded state after each step.
    pub recorded: Vec<Vec<f64>>,
    /// Start state, then the re-simulated state after each step.
    pub replayed: Vec<Vec<f64>>,
}

/// Reads the evaluation episodes of the run log at `path`.
pub fn load(path: &Path) -> Result<Recording, ReplayError> {
    recording(path, read(path)?)
}

/// Groups `contents`' episodes and steps.
pub fn recording(path: &Path, contents: RunLogContents) -> Result<Recording, ReplayError> {
    let config = contents
        .config()
        .cloned()
        .ok_or_else(|| ReplayError::NoConfig {
            path: path.to_path_buf(),
        })?;
    let mut episodes: Vec<(pb::EvalEpisode, Vec<pb::EvalStep>)> = Vec::new();
    let mut index = std::collections::HashMap::new();
    for l in contents.records {
        match l.record {
            Record::EvalEpisode(e) => {
                index.insert(e.episode, episodes.len());
                episodes.push((e, Vec::new()));
            }
            Record::EvalStep(s) => {
                if let Some(&i) = index.get(&s.episode) {
                    episodes[i].1.push(s);
                }
            }
            _ => {}
        }
    }
    Ok(Recording {
        path: path.to_path_buf(),
        config,
        episodes,
        truncated: contents.truncated,
    })
}

/// One [`EpisodeInfo`] per episode, in log order.
pub fn list(rec: &Recording) -> Vec<EpisodeInfo> {
    rec.episodes
        .iter()
        .map(|(e, steps)| EpisodeInfo {
            episode: e.episode,
            iteration: e.iteration,
            final_eval: e.final_eval,
            code: e.code,
            eps: e.eps,
            length: e.length,
            recorded_steps: steps.len(),
            mode_returns: e.mode_returns.clone(),
        })
        .collect()
}

/// Largest absolute difference; NaN anywhere counts as infinite, and so do vectors of
/// different lengths.
fn max_abs<A: Copy + Into<f64>, B: Copy + Into<f64>>(a: &[A], b: &[B]) -> f64 {
    if a.len() != b.len() {
        return f64::INFINITY;
    }
    a.iter()
        .zip(b)
        .map(|(&x, &y)| {
            let d = (x.into() - y.into()).abs();
            if d.is_nan() { f64::INFINITY } else { d }
        })
        .fold(0.0, f64::max)
}

/// Re-simulates episode `episode` of `rec` from its recorded start state and actions.
pub fn replay(rec: &Recording, episode: u32) -> Result<(ReplayReport, Trajectory), ReplayError> {
    let path = &rec.path;
    let Some((ep, steps)) = rec.episodes.iter().find(|(e, _)| e.episode == episode) else {
        let ids: Vec<u32> = rec.episodes.iter().map(|(e, _)| e.episode).collect();
        return Err(ReplayError::NoSuchEpisode {
            path: path.clone(),
            episode,
            count: ids.len(),
            range: match (ids.iter().min(), ids.iter().max()) {
                (Some(a), Some(b)) => format!("{a}..={b}"),
                _ => "none".into(),
            },
        });
    };
    let bad = |why: String| ReplayError::Episode {
        path: path.clone(),
        episode,
        why,
    };
    let env_err = |at: String| {
        move |source| ReplayError::Env {
            path: path.clone(),
            episode,
            at,
            source,
        }
    };
    if ep.start_state.is_empty() {
        return Err(bad("no start state recorded".into()));
    }
    let env_name = &rec.config.env;
    let n_modes = rec.config.n_modes as usize;
    // The env exactly as training and the actors build it (`make_training_env`: for
    // Pusher, Walker2d and Humanoid the expert-driven wrapper, whose state carries the
    // last observation after the simulator's; a task file plain), so the recorded
    // states fit it.
    let mut env: Box<dyn Env> = make_training_env(env_name, n_modes).map_err(env_err(format!(
        "building env `{env_name}` with {n_modes} modes"
    )))?;
    let spec = env.spec().clone();
    let mut obs = vec![0.0f32; spec.obs_dim];
    env.reset(ep.reset_seed, &mut obs)
        .map_err(env_err("reset".into()))?;
    let reset_deviation = max_abs(&env.state(), &ep.start_state);
    env.set_state(&ep.start_state)
        .map_err(env_err("start state".into()))?;
    let mut report = ReplayReport {
        file: path.clone(),
        episode,
        env: env_name.clone(),
        steps: 0,
        max_state_deviation: 0.0,
        max_state_deviation_step: 0,
        max_obs_deviation: 0.0,
        max_reward_deviation: 0.0,
        reset_deviation,
    };
    let mut traj = Trajectory {
        env: env_name.clone(),
        n_modes,
        recorded: vec![ep.start_state.clone()],
        replayed: vec![env.state()],
    };
    let mut rew = vec![0.0f32; spec.n_modes];
    for (i, s) in steps.iter().enumerate() {
        if s.step as usize != i {
            return Err(bad(format!(
                "step {} recorded where step {i} was expected",
                s.step
            )));
        }
        if s.action.len() != spec.act_dim {
            return Err(bad(format!(
                "step {i}: action has {} values, env `{env_name}` takes {}",
                s.action.len(),
                spec.act_dim
            )));
        }
        env.step(&s.action, &mut obs)
            .map_err(env_err(format!("step {i}")))?;
        env.mode_rewards(&mut rew);
        let state = env.state();
        let d = max_abs(&state, &s.state);
        if d > report.max_state_deviation {
            report.max_state_deviation = d;
            report.max_state_deviation_step = i;
        }
        report.max_obs_deviation = report.max_obs_deviation.max(max_abs(&obs, &s.next_obs));
        report.max_reward_deviation = report
            .max_reward_deviation
            .max(max_abs(&rew, &s.mode_rewards));
        report.steps += 1;
        traj.recorded.push(s.state.clone());
        traj.replayed.push(state);
    }
    Ok((report, traj))
}

/// The robot of a replayed episode: the env's bodies and their poses in each
/// re-simulated state of `traj`, with the episode's code; `None` for an env without
/// bodies (Traj2D).
pub fn episode_scene(
    rec: &Recording,
    episode: u32,
    traj: &Trajectory,
) -> Result<Option<(ess_envs::scene::Scene, super::scene::EpisodePoses, usize)>, ReplayError> {
    let env_err = |at: String| {
        move |source| ReplayError::Env {
            path: rec.path.clone(),
            episode,
            at,
            source,
        }
    };
    let mut env = make_training_env(&traj.env, traj.n_modes)
        .map_err(env_err(format!("building env `{}`", traj.env)))?;
    let Some(scene) = env.scene() else {
        return Ok(None);
    };
    let states = traj.replayed.iter().map(Vec::as_slice);
    let poses = super::scene::poses_of(env.as_mut(), states)
        .map_err(|(k, source)| env_err(format!("state {k}"))(source))?;
    let code = rec
        .episodes
        .iter()
        .find(|(e, _)| e.episode == episode)
        .map_or(0, |(e, _)| e.code as usize);
    Ok(Some((scene, poses, code)))
}

/// Length of the `qpos` block of a MuJoCo env's state (it follows the time, the first
/// value of `mjSTATE_INTEGRATION`); `None` for Traj2D and unknown envs.
pub fn qpos_len(env: &str) -> Option<usize> {
    match env {
        "reacher" => Some(2),
        "pusher" => Some(9),
        "walker2d" => Some(9),
        // Free root joint (3 position + 4 quaternion) and 17 hinges.
        "humanoid" => Some(24),
        _ => None,
    }
}

/// Draws `traj` into `out` (and a body path into `<stem>-path.png` for MuJoCo envs);
/// returns the files written.
pub fn plot(out: &Path, traj: &Trajectory, title: &str) -> Result<Vec<PathBuf>, ReplayError> {
    use crate::eval::plot::{TrajPanel, draw_curves, draw_trajectories};
    let xy = |states: &[Vec<f64>], i: usize, j: usize| -> Vec<(f32, f32)> {
        states
            .iter()
            .filter_map(|s| Some((*s.get(i)? as f32, *s.get(j)? as f32)))
            .collect()
    };
    if traj.env == "traj2d" {
        draw_trajectories(
            out,
            &[TrajPanel {
                title: format!("{title}: x-y path"),
                paths: vec![(xy(&traj.recorded, 0, 1), 0), (xy(&traj.replayed, 0, 1), 2)],
            }],
            600,
        )?;
        return Ok(vec![out.to_path_buf()]);
    }
    let nq = qpos_len(&traj.env).unwrap_or(0);
    let series: Vec<(String, Vec<(f64, f64)>)> = (0..nq)
        .map(|j| {
            (
                format!("qpos[{j}]"),
                traj.recorded
                    .iter()
                    .enumerate()
                    .filter_map(|(t, s)| Some((t as f64, *s.get(1 + j)?)))
                    .collect(),
            )
        })
        .collect();
    draw_curves(out, &format!("{title}: joint positions"), "step", &series)?;
    let mut written = vec![out.to_path_buf()];
    let paths = body_paths(traj);
    if !paths.is_empty() {
        let stem = out
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "replay".into());
        let path_png = out.with_file_name(format!("{stem}-path.png"));
        draw_trajectories(
            &path_png,
            &[TrajPanel {
                title: format!("{title}: {}", body_path_name(&traj.env)),
                paths,
            }],
            600,
        )?;
        written.push(path_png);
    }
    Ok(written)
}

fn body_path_name(env: &str) -> &'static str {
    match env {
        "reacher" => "fingertip x-y",
        "pusher" => "fingertip (red) and object (green) x-y",
        "walker2d" => "root x-z",
        "humanoid" => "root x-y",
        _ => "path",
    }
}

/// Body paths of a MuJoCo trajectory (recorded states), by restoring each state into
/// the env where a body position needs forward kinematics. A recorded state may be the
/// expert-driven wrapper's (`make_env`: the plain env's state followed by the last
/// observation), so only its plain-env prefix is restored.
fn body_paths(traj: &Trajectory) -> Vec<(Vec<(f32, f32)>, usize)> {
    let root = |i: usize, j: usize| -> Vec<(f32, f32)> {
        traj.recorded
            .iter()
            .filter_map(|s| Some((*s.get(1 + i)? as f32, *s.get(1 + j)? as f32)))
            .collect()
    };
    match traj.env.as_str() {
        "walker2d" => vec![(root(0, 1), 2)],
        "humanoid" => vec![(root(0, 1), 2)],
        "reacher" => {
            let Ok(mut env) = Reacher::new(ReacherConfig {
                n_modes: traj.n_modes,
                ..ReacherConfig::default()
            }) else {
                return Vec::new();
            };
            let n = env.state().len();
            let tip: Vec<(f32, f32)> = traj
                .recorded
                .iter()
                .filter_map(|s| {
                    env.set_state(s.get(..n)?).ok()?;
                    let p = env.fingertip();
                    Some((p[0] as f32, p[1] as f32))
                })
                .collect();
            vec![(tip, 0)]
        }
        "pusher" => {
            let Ok(mut env) = Pusher::new(PusherConfig {
                n_modes: traj.n_modes,
                ..PusherConfig::default()
            }) else {
                return Vec::new();
            };
            let n = env.state().len();
            let mut tip = Vec::new();
            let mut object = Vec::new();
            for s in &traj.recorded {
                if let Some(s) = s.get(..n)
                    && env.set_state(s).is_ok()
                {
                    let p = env.fingertip();
                    let o = env.object_position();
                    tip.push((p[0] as f32, p[1] as f32));
                    object.push((o[0] as f32, o[1] as f32));
                }
            }
            vec![(tip, 0), (object, 1)]
        }
        _ => Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runlog::RunLog;
    use ess_actor::{LatentSpec, PolicyWeights, eval_episode};
    use ess_envs::make_env;
    use ess_proto::config::{ConfigBuilder, LatentPrior};
    use ess_proto::{Mlp, MlpLayout};

    /// A run log of `per_code` evaluation episodes per code of a fixed non-trivial
    /// policy on `env`, written through [`RunLog`] as `ess train` does.
    fn record_episodes(dir: &Path, env: &str, n_modes: usize, per_code: usize) -> PathBuf {
        let mut b = ConfigBuilder::new();
        b.set(&format!("env.name=\"{env}\"")).unwrap();
        b.set(&format!("env.n_modes={n_modes}")).unwrap();
        let cfg = b.build().unwrap();
        let mut e = make_env(env, n_modes).unwrap();
        let s = e.spec().clone();
        let layout = MlpLayout::new(s.obs_dim + 1 + n_modes, &[16], s.act_dim).unwrap();
        let params = (0..layout.n_params())
            .map(|i| (i as f32 * 0.37).sin() * 0.5)
            .collect();
        let w = PolicyWeights {
            version: 1,
            mean: Mlp::new(layout, params).unwrap(),
            log_std: vec![-0.5; s.act_dim],
            prior_logits: vec![0.0; n_modes],
            obs_mean: vec![0.0; s.obs_dim],
            obs_std: vec![1.0; s.obs_dim],
        };
        let latent = LatentSpec {
            prior: LatentPrior::Uniform,
            n_codes: n_modes,
            tau: 1.0,
            use_eps: true,
        };
        let episodes: Vec<_> = (0..n_modes * per_code)
            .map(|j| {
                eval_episode(
                    e.as_mut(),
                    &w,
                    &latent,
                    j % n_modes,
                    0.3 - 0.1 * j as f32,
                    j as u64 + 11,
                )
                .unwrap()
            })
            .collect();
        let path = dir.join("run.mcap");
        let mut log = RunLog::create(&path, &cfg).unwrap();
        log.eval_episodes(0, true, &episodes, None).unwrap();
        log.finish().unwrap();
        path
    }

    fn replays_within_tolerance(env: &str, n_modes: usize) {
        let dir = tempfile::tempdir().unwrap();
        let path = record_episodes(dir.path(), env, n_modes, 1);
        let rec = load(&path).unwrap();
        let rows = list(&rec);
        assert_eq!(rows.len(), n_modes);
        for r in &rows {
            assert!(
                r.length > 1 && r.recorded_steps == r.length as usize,
                "{r:?}"
            );
            let (report, traj) = replay(&rec, r.episode).unwrap();
            assert_eq!(report.steps, r.length as usize);
            assert!(report.max_deviation() < 1e-6, "{report:?}");
            assert_eq!(report.reset_deviation, 0.0, "{report:?}");
            // The episode moved: states differ along the way.
            assert!(max_abs(&traj.recorded[0], &traj.recorded[report.steps]) > 1e-3);
        }
    }

    #[test]
    fn traj2d_episodes_replay_within_1e_6_of_the_recording() {
        replays_within_tolerance("traj2d", 4);
    }

    #[test]
    fn reacher_episodes_replay_within_1e_6_of_the_recording() {
        replays_within_tolerance("reacher", 2);
    }

    #[test]
    fn pusher_episodes_replay_within_1e_6_of_the_recording() {
        replays_within_tolerance("pusher", 6);
    }

    #[test]
    fn walker2d_episodes_replay_within_1e_6_of_the_recording() {
        replays_within_tolerance("walker2d", 3);
    }

    #[test]
    fn humanoid_episodes_replay_within_1e_6_of_the_recording() {
        replays_within_tolerance("humanoid", 3);
    }

    #[test]
    fn a_changed_action_shows_up_as_a_deviation() {
        let dir = tempfile::tempdir().unwrap();
        let path = record_episodes(dir.path(), "reacher", 2, 1);
        let mut rec = load(&path).unwrap();
        let steps = &mut rec.episodes[0].1;
        let k = steps.len() / 2;
        steps[k].action[0] = -steps[k].action[0] + 0.5;
        let (report, _) = replay(&rec, 0).unwrap();
        assert!(report.max_state_deviation > 1e-6, "{report:?}");
        assert!(report.max_state_deviation_step >= k, "{report:?}");
    }

    #[test]
    fn a_missing_episode_is_named_with_the_file_and_the_available_range() {
        let dir = tempfile::tempdir().unwrap();
        let path = record_episodes(dir.path(), "traj2d", 4, 1);
        let rec = load(&path).unwrap();
        let e = replay(&rec, 9).unwrap_err().to_string();
        assert!(
            e.contains("run.mcap") && e.contains("episode 9") && e.contains("0..=3"),
            "{e}"
        );
    }

    #[test]
    fn reacher_plot_draws_joint_positions_and_the_fingertip_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = record_episodes(dir.path(), "reacher", 2, 1);
        let rec = load(&path).unwrap();
        let (_, traj) = replay(&rec, 1).unwrap();
        // qpos_len fits the state: the shoulder/elbow angles follow the time.
        let mut env = Reacher::new(ReacherConfig {
            n_modes: 2,
            ..ReacherConfig::default()
        })
        .unwrap();
        env.set_state(&traj.recorded[5]).unwrap();
        assert_eq!(
            env.joint_angles().to_vec(),
            traj.recorded[5][1..1 + qpos_len("reacher").unwrap()].to_vec()
        );
        assert_eq!(body_paths(&traj)[0].0.len(), traj.recorded.len());
        let out = dir.path().join("ep1.png");
        let files = plot(&out, &traj, "reacher episode 1").unwrap();
        assert_eq!(files, vec![out.clone(), dir.path().join("ep1-path.png")]);
        for f in files {
            assert!(
                std::fs::metadata(&f).unwrap().len() > 1000,
                "{}",
                f.display()
            );
        }
    }

    #[test]
    fn pusher_plot_draws_the_fingertip_and_object_paths_of_every_state() {
        let dir = tempfile::tempdir().unwrap();
        let path = record_episodes(dir.path(), "pusher", 6, 1);
        let rec = load(&path).unwrap();
        let (_, traj) = replay(&rec, 2).unwrap();
        let paths = body_paths(&traj);
        assert_eq!(paths.len(), 2);
        for (p, _) in &paths {
            assert_eq!(p.len(), traj.recorded.len());
        }
        // The fingertip moved.
        let tip = &paths[0].0;
        assert!(
            (tip[0].0 - tip[tip.len() - 1].0).abs() + (tip[0].1 - tip[tip.len() - 1].1).abs()
                > 1e-3
        );
        let out = dir.path().join("ep2.png");
        let files = plot(&out, &traj, "pusher episode 2").unwrap();
        assert_eq!(files, vec![out.clone(), dir.path().join("ep2-path.png")]);
    }
}
