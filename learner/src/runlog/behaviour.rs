//! What each code does beside what its expert does, for envs that move (Walker2d,
//! Humanoid): `ess report` prints each code's episode length and forward velocity
//! beside its mode's expert, and draws the root body's forward position over time per
//! code (`behaviours.png`, the locomotion counterpart of Traj2D's trajectories.png).
//!
//! The policy's side comes from the run log's final-evaluation episodes: every
//! recorded state is restored into the env ([`Env::set_state`]), which gives the
//! forward velocity of that step ([`Env::forward_velocity`]) and the root body's
//! position ([`Env::body_poses`]). The expert's side is rolled out fresh with the
//! shipped experts ([`ess_envs::make_env`]).

use super::replay::{Recording, ReplayError};
use crate::eval::plot::draw_curves;
use ess_envs::{Env, EnvError, make_env, make_training_env};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::Path;

/// One code's (or expert mode's) episodes, summarised.
#[derive(Debug, Clone, PartialEq)]
pub struct Behaviour {
    /// The code (policy) or mode (expert).
    pub index: usize,
    /// Episodes.
    pub episodes: usize,
    /// Mean episode length in steps.
    pub length: f64,
    /// Mean forward velocity over every step of every episode (m/s).
    pub velocity: f64,
    /// The root body's forward position (x) after each step, one series per episode.
    pub tracks: Vec<Vec<f64>>,
}

/// The root body's forward position and the forward velocity of the env's current
/// state; `None` where the env has no forward velocity.
fn sample(env: &dyn Env) -> Option<(f64, f64)> {
    let v = env.forward_velocity()?;
    let x = env.body_poses().get(1).map_or(f64::NAN, |p| p.pos[0]);
    Some((x, v))
}

fn summarise(index: usize, runs: Vec<(Vec<f64>, Vec<f64>)>) -> Behaviour {
    let steps: usize = runs.iter().map(|(x, _)| x.len()).sum();
    let v_sum: f64 = runs.iter().flat_map(|(_, v)| v).sum();
    Behaviour {
        index,
        episodes: runs.len(),
        length: steps as f64 / runs.len().max(1) as f64,
        velocity: v_sum / steps.max(1) as f64,
        tracks: runs.into_iter().map(|(x, _)| x).collect(),
    }
}

/// Each code's behaviour in the final evaluation of `rec`; `None` when the env has no
/// forward velocity (nothing to compare) or the log holds no final evaluation.
pub fn policy_behaviour(rec: &Recording) -> Result<Option<Vec<Behaviour>>, ReplayError> {
    let name = &rec.config.env;
    let n_modes = rec.config.n_modes as usize;
    let env_err = |at: String| {
        move |source| ReplayError::Env {
            path: rec.path.clone(),
            episode: 0,
            at,
            source,
        }
    };
    let mut env = make_training_env(name, n_modes).map_err(env_err(format!(
        "building env `{name}` with {n_modes} modes"
    )))?;
    let mut by_code: Vec<Vec<(Vec<f64>, Vec<f64>)>> = Vec::new();
    for (ep, steps) in rec.episodes.iter().filter(|(e, _)| e.final_eval) {
        let (mut xs, mut vs) = (Vec::new(), Vec::new());
        for s in steps {
            env.set_state(&s.state).map_err(|source| ReplayError::Env {
                path: rec.path.clone(),
                episode: ep.episode,
                at: format!("step {}", s.step),
                source,
            })?;
            let Some((x, v)) = sample(env.as_ref()) else {
                return Ok(None);
            };
            xs.push(x);
            vs.push(v);
        }
        let code = ep.code as usize;
        if by_code.len() <= code {
            by_code.resize_with(code + 1, Vec::new);
        }
        by_code[code].push((xs, vs));
    }
    if by_code.is_empty() {
        return Ok(None);
    }
    Ok(Some(
        by_code
            .into_iter()
            .enumerate()
            .map(|(k, runs)| summarise(k, runs))
            .collect(),
    ))
}

/// `episodes` episodes of each mode's expert on `env` (reset seeds from `seed`).
pub fn expert_behaviour(
    env: &str,
    n_modes: usize,
    episodes: usize,
    seed: u64,
) -> Result<Vec<Behaviour>, EnvError> {
    let mut env = make_env(env, n_modes)?;
    let spec = env.spec().clone();
    let mut obs = vec![0.0f32; spec.obs_dim];
    let mut act = vec![0.0f32; spec.act_dim];
    let mut out = Vec::new();
    for mode in 0..spec.n_modes {
        let mut runs = Vec::new();
        for e in 0..episodes {
            let s = seed ^ ((mode as u64) << 32) ^ (e as u64 + 1);
            let mut rng = ChaCha8Rng::seed_from_u64(s);
            env.reset(s, &mut obs)?;
            let (mut xs, mut vs) = (Vec::new(), Vec::new());
            for _ in 0..spec.max_steps.max(1) {
                env.expert_action(mode, &mut rng, &mut act)?;
                let done = env.step(&act, &mut obs)?.done();
                if let Some((x, v)) = sample(env.as_ref()) {
                    xs.push(x);
                    vs.push(v);
                }
                if done {
                    break;
                }
            }
            runs.push((xs, vs));
        }
        out.push(summarise(mode, runs));
    }
    Ok(out)
}

/// The mean of `tracks` at each step over the episodes still running then.
fn mean_track(tracks: &[Vec<f64>]) -> Vec<(f64, f64)> {
    let longest = tracks.iter().map(Vec::len).max().unwrap_or(0);
    (0..longest)
        .filter_map(|t| {
            let alive: Vec<f64> = tracks.iter().filter_map(|x| x.get(t).copied()).collect();
            (!alive.is_empty()).then(|| (t as f64, alive.iter().sum::<f64>() / alive.len() as f64))
        })
        .collect()
}

/// Draws each code's mean root position over time beside its expert's into `out`.
pub fn plot_behaviours(
    out: &Path,
    title: &str,
    policy: &[Behaviour],
    expert: &[Behaviour],
) -> Result<(), crate::eval::plot::PlotError> {
    let mut series = Vec::new();
    for b in policy {
        series.push((format!("code {}", b.index), mean_track(&b.tracks)));
    }
    for b in expert {
        series.push((format!("expert mode {}", b.index), mean_track(&b.tracks)));
    }
    draw_curves(
        out,
        &format!("{title}: root forward position (m), mean over episodes"),
        "step",
        &series,
    )
}

/// Expert episodes per mode that [`section`] rolls out.
pub const EXPERT_EPISODES: usize = 5;

/// `ess report`'s behaviour view of the run in `dir` (its `run.mcap`): a Markdown
/// table of each code's episode length, forward velocity and normalised reward
/// (`reward_per_code`, from summary.json) beside the expert of the mode the
/// evaluation matched it to (`assignment`; the code's own index where absent), and
/// `<dir>/behaviours.png`. `None` for runs whose env does not move (or whose log has no
/// final evaluation).
pub fn section(
    dir: &Path,
    reward_per_code: &[f64],
    assignment: &[usize],
) -> anyhow::Result<Option<String>> {
    use anyhow::Context as _;
    use std::fmt::Write as _;
    let log = dir.join("run.mcap");
    if !log.exists() {
        return Ok(None);
    }
    let rec = super::replay::load(&log)?;
    let Some(policy) = policy_behaviour(&rec)? else {
        return Ok(None);
    };
    let (env, k) = (&rec.config.env, rec.config.n_modes as usize);
    let expert = expert_behaviour(env, k, EXPERT_EPISODES, 0)
        .with_context(|| format!("{}: rolling out the experts of `{env}`", dir.display()))?;
    let png = dir.join("behaviours.png");
    plot_behaviours(
        &png,
        &format!("{env} {}", rec.config.method),
        &policy,
        &expert,
    )?;
    let mut md = format!(
        "\n### {}: each code beside its mode's expert (final evaluation; experts: {EXPERT_EPISODES} episodes per mode)\n\n",
        dir.display()
    );
    md.push_str("| code | episodes | length | velocity m/s | norm. reward | matched mode | expert length | expert velocity m/s |\n|---|---|---|---|---|---|---|---|\n");
    for b in &policy {
        let reward = reward_per_code
            .get(b.index)
            .map_or("-".into(), |r| format!("{r:.3}"));
        let mode = assignment.get(b.index).copied().unwrap_or(b.index);
        let (el, ev) = expert.get(mode).map_or(("-".into(), "-".into()), |e| {
            (format!("{:.0}", e.length), format!("{:+.2}", e.velocity))
        });
        let _ = writeln!(
            md,
            "| {} | {} | {:.0} | {:+.2} | {reward} | {mode} | {el} | {ev} |",
            b.index, b.episodes, b.length, b.velocity
        );
    }
    let _ = writeln!(md, "\nDrawn: {}", png.display());
    Ok(Some(md))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_track_averages_the_episodes_still_running() {
        let m = mean_track(&[vec![1.0, 2.0, 3.0], vec![3.0]]);
        assert_eq!(m, vec![(0.0, 2.0), (1.0, 2.0), (2.0, 3.0)]);
    }

    #[test]
    fn humanoid_experts_run_forward_backward_and_stand() {
        let b = expert_behaviour("humanoid", 3, 1, 7).expect("experts");
        assert_eq!(b.len(), 3);
        assert!(b[0].velocity > 0.5, "forward expert: {:?}", b[0].velocity);
        assert!(b[1].velocity < -0.2, "backward expert: {:?}", b[1].velocity);
        assert!(b[2].velocity.abs() < 0.2, "balancer: {:?}", b[2].velocity);
        // The root's position follows the velocity: the forward runner ends ahead.
        let last = |b: &Behaviour| *b.tracks[0].last().expect("steps");
        assert!(last(&b[0]) > last(&b[2]) + 1.0);
        assert!(b.iter().all(|m| m.length > 100.0), "{b:?}");
    }

    #[test]
    fn traj2d_has_no_velocity_view() {
        let mut env = make_training_env("traj2d", 4).expect("env");
        let mut obs = vec![0.0; env.spec().obs_dim];
        env.reset(1, &mut obs).expect("reset");
        assert!(sample(env.as_ref()).is_none());
    }
}
