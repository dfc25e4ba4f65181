//! Generating a dataset from the shipped experts (module doc of [`super`],
//! "Generation").

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::env::{EnvError, ScriptedExpert};
use crate::registry::make_env;

use super::{DemoError, DemoMeta, DemoSpec, DemoSplit, Demos, FORMAT_VERSION};

/// Relative frequency of each mode in the unlabeled data: the largest is 1.0, the
/// smallest `1 / imbalance_ratio`.
///
/// Rule: with `n_modes <= 3` each mode is its own group; otherwise modes go in groups
/// of two (modes 0 and 1 first, then 2 and 3, ...; an odd last mode is alone). With
/// `G` groups, group `g` gets weight `imbalance_ratio^(-g / (G - 1))` (1.0 when
/// `G == 1`). Examples with ratio 100: 4 modes `[1, 1, 0.01, 0.01]`; 6 modes
/// `[1, 1, 0.1, 0.1, 0.01, 0.01]`; 3 modes `[1, 0.1, 0.01]`; 2 modes `[1, 0.01]`.
pub fn mode_weights(n_modes: usize, imbalance_ratio: f64) -> Vec<f64> {
    let group_size = if n_modes <= 3 { 1 } else { 2 };
    let n_groups = n_modes.div_ceil(group_size);
    (0..n_modes)
        .map(|k| {
            let g = k / group_size;
            if n_groups <= 1 {
                1.0
            } else {
                imbalance_ratio.powf(-(g as f64) / (n_groups - 1) as f64)
            }
        })
        .collect()
}

/// Labeled steps per mode: `ceil(label_ratio * n_unlabeled_steps / n_modes)`.
pub fn labeled_steps_per_mode(label_ratio: f64, n_unlabeled_steps: usize, n_modes: usize) -> usize {
    (label_ratio * n_unlabeled_steps as f64 / n_modes as f64).ceil() as usize
}

/// Rolls one expert episode of `mode` from `env.reset(seed)` until it ends. The expert's
/// own randomness is a `ChaCha8Rng` seeded with `seed` on stream 1 (the env's reset
/// uses stream 0). Episode indices are 0; `reward` is the evaluation reward of `mode`.
pub fn expert_episode(
    env: &mut dyn ScriptedExpert,
    mode: usize,
    seed: u64,
) -> Result<DemoSplit, EnvError> {
    let spec = env.spec().clone();
    if mode >= spec.n_modes {
        return Err(EnvError::ModeOutOfRange {
            mode,
            n_modes: spec.n_modes,
        });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(1);
    let mut obs = vec![0.0; spec.obs_dim];
    let mut next = vec![0.0; spec.obs_dim];
    let mut act = vec![0.0; spec.act_dim];
    let mut rewards = vec![0.0; spec.n_modes];
    let mut split = DemoSplit::default();
    env.reset(seed, &mut obs)?;
    // The env's own limit ends the loop; the bound guards against a broken env.
    for _ in 0..spec.max_steps.max(1) {
        env.expert_action(mode, &mut rng, &mut act)?;
        let out = env.step(&act, &mut next)?;
        env.mode_rewards(&mut rewards);
        split.obs.extend_from_slice(&obs);
        split.act.extend_from_slice(&act);
        split.next_obs.extend_from_slice(&next);
        split.mode.push(mode as u32);
        split.episode.push(0);
        split.reward.push(rewards[mode]);
        if out.terminated || out.truncated {
            break;
        }
        std::mem::swap(&mut obs, &mut next);
    }
    Ok(split)
}

fn validate_spec(spec: &DemoSpec) -> Result<(), DemoError> {
    if !(spec.label_ratio > 0.0 && spec.label_ratio <= 1.0) {
        return Err(DemoError::BadSpec {
            field: "label_ratio",
            value: spec.label_ratio.to_string(),
            reason: "must lie in (0, 1]",
        });
    }
    if !(spec.imbalance_ratio.is_finite() && spec.imbalance_ratio >= 1.0) {
        return Err(DemoError::BadSpec {
            field: "imbalance_ratio",
            value: spec.imbalance_ratio.to_string(),
            reason: "must be finite and at least 1",
        });
    }
    if spec.n_modes < 2 {
        return Err(DemoError::BadSpec {
            field: "n_modes",
            value: spec.n_modes.to_string(),
            reason: "must be at least 2",
        });
    }
    if spec.majority_episodes < 1 {
        return Err(DemoError::BadSpec {
            field: "majority_episodes",
            value: spec.majority_episodes.to_string(),
            reason: "must be at least 1",
        });
    }
    Ok(())
}

/// Generates the dataset described by `spec` (see the module docs for the rules).
pub fn generate_demos(spec: &DemoSpec) -> Result<Demos, DemoError> {
    validate_spec(spec)?;
    let mut env = make_env(&spec.env, spec.n_modes)?;
    let env_spec = env.spec().clone();
    let n_modes = spec.n_modes;
    let mut seeds = ChaCha8Rng::seed_from_u64(spec.seed);

    let episodes_per_mode: Vec<usize> = mode_weights(n_modes, spec.imbalance_ratio)
        .iter()
        .map(|w| ((spec.majority_episodes as f64 * w).round() as usize).max(1))
        .collect();
    let mut episodes = Vec::with_capacity(episodes_per_mode.iter().sum());
    for (mode, &count) in episodes_per_mode.iter().enumerate() {
        for _ in 0..count {
            episodes.push(expert_episode(env.as_mut(), mode, seeds.random())?);
        }
    }
    episodes.shuffle(&mut seeds);
    let mut unlabeled = DemoSplit::default();
    for ep in &episodes {
        unlabeled.extend(ep);
    }

    let per_mode = labeled_steps_per_mode(spec.label_ratio, unlabeled.len(), n_modes);
    let mut labeled = DemoSplit::default();
    for mode in 0..n_modes {
        let mut part = DemoSplit::default();
        while part.len() < per_mode {
            part.extend(&expert_episode(env.as_mut(), mode, seeds.random())?);
        }
        part.truncate(per_mode, env_spec.obs_dim, env_spec.act_dim);
        labeled.extend(&part);
    }

    let meta = DemoMeta {
        format_version: FORMAT_VERSION,
        env: spec.env.clone(),
        obs_dim: env_spec.obs_dim,
        act_dim: env_spec.act_dim,
        n_modes,
        episode_len: env_spec.max_steps,
        label_ratio: spec.label_ratio,
        imbalance_ratio: spec.imbalance_ratio,
        majority_episodes: spec.majority_episodes,
        seed: spec.seed,
        unlabeled_episodes_per_mode: episodes_per_mode,
        unlabeled_steps_per_mode: unlabeled.steps_per_mode(n_modes),
        labeled_steps_per_mode: labeled.steps_per_mode(n_modes),
        generator: format!("ess {}", env!("CARGO_PKG_VERSION")),
        source: None,
    };
    tracing::info!(
        env = %spec.env,
        unlabeled_steps = unlabeled.len(),
        labeled_steps = labeled.len(),
        episodes_per_mode = ?meta.unlabeled_episodes_per_mode,
        "generated demonstrations"
    );
    Ok(Demos {
        meta,
        unlabeled,
        labeled,
    })
}
