//! Figures a run writes: `trajectories.png` (the paper's Fig. 1 for Traj2D: expert
//! demonstrations beside the learned policy's trajectories, one colour per latent code)
//! and `curves.png` (NMI, ENT and normalised task reward over training, cf. Fig. 5).

use crate::eval::plot::{TrajPanel, draw_curves, draw_trajectories};
use anyhow::Result;
use ess_actor::EvalEpisode;
use ess_envs::Demos;
use std::path::Path;

/// Position `(x, y)` of a Traj2D observation: its last two floats (time t).
fn position(obs: &[f32]) -> (f32, f32) {
    let n = obs.len();
    (obs[n - 2], obs[n - 1])
}

/// Draws expert demonstrations (up to 20 episodes per mode, so the imbalance shows)
/// beside up to 5 evaluation episodes per code of the learned policy.
pub fn plot_traj2d(
    path: &Path,
    demos: &Demos,
    episodes: &[EvalEpisode],
    method: &str,
    n_modes: usize,
) -> Result<()> {
    let od = demos.meta.obs_dim;
    let u = &demos.unlabeled;
    let mut expert_paths: Vec<(Vec<(f32, f32)>, usize)> = Vec::new();
    let mut per_mode = vec![0usize; n_modes];
    let mut start = 0;
    while start < u.len() {
        let ep = u.episode[start];
        let mut end = start;
        while end < u.len() && u.episode[end] == ep {
            end += 1;
        }
        let mode = u.mode[start] as usize;
        if mode < n_modes && per_mode[mode] < 20 {
            per_mode[mode] += 1;
            let mut pts = vec![position(&u.obs[start * od..(start + 1) * od])];
            pts.extend((start..end).map(|i| position(&u.next_obs[i * od..(i + 1) * od])));
            expert_paths.push((pts, mode));
        }
        start = end;
    }
    let mut policy_paths = Vec::new();
    let mut per_code = vec![0usize; n_modes];
    for ep in episodes {
        if ep.code < n_modes && per_code[ep.code] < 5 && !ep.obs.is_empty() {
            per_code[ep.code] += 1;
            let mut pts = vec![position(&ep.obs[..od])];
            pts.extend(ep.next_obs.chunks_exact(od).map(position));
            policy_paths.push((pts, ep.code));
        }
    }
    let counts: Vec<String> = demos
        .meta
        .unlabeled_episodes_per_mode
        .iter()
        .map(|c| c.to_string())
        .collect();
    let panels = [
        TrajPanel {
            title: format!("demos, episodes/mode {}", counts.join(":")),
            paths: expert_paths,
        },
        TrajPanel {
            title: format!("{method}: colour = latent code"),
            paths: policy_paths,
        },
    ];
    draw_trajectories(path, &panels, 600)?;
    Ok(())
}

/// One evaluation point: env steps, NMI, ENT, normalised task reward.
pub type CurvePoint = (usize, f64, f64, f64);

/// Draws the evaluation metrics over env steps.
pub fn plot_curves(path: &Path, method: &str, points: &[CurvePoint]) -> Result<()> {
    let series = vec![
        (
            "NMI".to_string(),
            points.iter().map(|p| (p.0 as f64, p.1)).collect(),
        ),
        (
            "ENT".to_string(),
            points.iter().map(|p| (p.0 as f64, p.2)).collect(),
        ),
        (
            "normalized reward".to_string(),
            points.iter().map(|p| (p.0 as f64, p.3)).collect(),
        ),
    ];
    draw_curves(path, &format!("{method}: evaluation"), "env steps", &series)?;
    Ok(())
}
