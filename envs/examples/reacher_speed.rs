//! Single-thread speed of the Reacher env against its ceiling, plus the scripted
//! expert's accuracy.
//!
//! Prints (1) the raw `mj_step` rate on [`REACHER_MJCF`] and the env-step ceiling it
//! implies (`rate / frame_skip`), (2) the rate of `Reacher::step` with uniformly random
//! actions (resets included), and (3) the expert's mean final distance to its target.
//!
//! ```text
//! source .deps/env.sh && cargo run --release -p ess-envs --example reacher_speed
//! ```

use std::time::Instant;

use ess_envs::reacher::REACHER_MJCF;
use ess_envs::{Env, EnvError, Reacher, ReacherConfig, ScriptedExpert};
use mujoco_rs::prelude::{MjData, MjModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Physics steps timed for the raw rate.
const RAW_STEPS: usize = 400_000;
/// Env steps timed for the env rate.
const ENV_STEPS: usize = 200_000;

fn main() -> Result<(), EnvError> {
    let cfg = ReacherConfig::default();
    let model = MjModel::from_xml_string(REACHER_MJCF).map_err(|e| EnvError::Model {
        reason: e.to_string(),
    })?;
    let mut data = MjData::new(&model);
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let start = Instant::now();
    for i in 0..RAW_STEPS {
        if i % cfg.frame_skip == 0 {
            for c in data.ctrl_mut() {
                *c = rng.random_range(-1.0..=1.0);
            }
        }
        if i % (cfg.frame_skip * cfg.max_steps) == 0 {
            data.reset();
        }
        data.step();
    }
    let raw = RAW_STEPS as f64 / start.elapsed().as_secs_f64();
    println!(
        "raw mj_step: {:.0} steps/s ({:.2} us each); ceiling at frame_skip {}: {:.0} env steps/s",
        raw,
        1e6 / raw,
        cfg.frame_skip,
        raw / cfg.frame_skip as f64
    );

    let mut env = Reacher::new(cfg.clone())?;
    let mut obs = [0.0f32; Reacher::OBS_DIM];
    let mut rewards = vec![0.0f32; cfg.n_modes];
    let mut seed = 0;
    env.reset(seed, &mut obs)?;
    let start = Instant::now();
    for _ in 0..ENV_STEPS {
        let a = [rng.random_range(-1.0..=1.0), rng.random_range(-1.0..=1.0)];
        let out = env.step(&a, &mut obs)?;
        env.mode_rewards(&mut rewards);
        if out.done() {
            seed += 1;
            env.reset(seed, &mut obs)?;
        }
    }
    let rate = ENV_STEPS as f64 / start.elapsed().as_secs_f64();
    println!(
        "Reacher::step (+ mode_rewards, resets): {:.0} env steps/s ({:.2} us each), {:.0}% of the ceiling",
        rate,
        1e6 / rate,
        100.0 * rate * cfg.frame_skip as f64 / raw
    );

    for mode in 0..cfg.n_modes {
        let mut dists = Vec::new();
        for ep in 0..50 {
            env.reset(10_000 + ep, &mut obs)?;
            let mut act = [0.0f32; 2];
            loop {
                env.expert_action(mode, &mut rng, &mut act)?;
                if env.step(&act, &mut obs)?.done() {
                    break;
                }
            }
            dists.push(env.distance_to_target(mode).unwrap_or(f64::NAN));
        }
        let mean = dists.iter().sum::<f64>() / dists.len() as f64;
        let max = dists.iter().copied().fold(0.0, f64::max);
        let within = dists.iter().filter(|&&d| d < 0.02).count();
        println!(
            "expert mode {mode}: final distance mean {mean:.4} m, max {max:.4} m, {within}/50 within 0.02 m"
        );
    }
    Ok(())
}
