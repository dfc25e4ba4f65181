//! Single-thread speed of the Pusher env against its ceiling.
//!
//! Prints (1) the raw `mj_step` rate on [`PUSHER_MJCF`] with uniformly random controls
//! and the env-step ceiling it implies (`rate / frame_skip`), and (2) the rate of
//! `Pusher::step` plus `mode_rewards` with uniformly random actions (resets included).
//!
//! ```text
//! source .deps/env.sh && cargo run --release -p ess-envs --example pusher_speed
//! ```

use std::time::Instant;

use ess_envs::pusher::PUSHER_MJCF;
use ess_envs::{Env, EnvError, Pusher, PusherConfig};
use mujoco_rs::prelude::{MjData, MjModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Physics steps timed for the raw rate.
const RAW_STEPS: usize = 1_000_000;
/// Env steps timed for the env rate.
const ENV_STEPS: usize = 200_000;

fn main() -> Result<(), EnvError> {
    let cfg = PusherConfig::default();
    let model = MjModel::from_xml_string(PUSHER_MJCF).map_err(|e| EnvError::Model {
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

    let mut env = Pusher::new(cfg.clone())?;
    let mut obs = [0.0f32; Pusher::OBS_DIM];
    let mut act = [0.0f32; Pusher::ACT_DIM];
    let mut rewards = vec![0.0f32; cfg.n_modes];
    let mut seed = 0;
    env.reset(seed, &mut obs)?;
    let start = Instant::now();
    for _ in 0..ENV_STEPS {
        for a in &mut act {
            *a = rng.random_range(-1.0..=1.0);
        }
        let out = env.step(&act, &mut obs)?;
        env.mode_rewards(&mut rewards);
        if out.done() {
            seed += 1;
            env.reset(seed, &mut obs)?;
        }
    }
    let rate = ENV_STEPS as f64 / start.elapsed().as_secs_f64();
    println!(
        "Pusher::step (+ mode_rewards, resets): {:.0} env steps/s ({:.2} us each), {:.0}% of the ceiling",
        rate,
        1e6 / rate,
        100.0 * rate * cfg.frame_skip as f64 / raw
    );
    Ok(())
}
