//! Single-thread speed of the Walker2d and Humanoid envs against their ceilings.
//!
//! For each env it prints (1) the rate of `Env::step` (+ `mode_rewards`) with uniformly
//! random actions, resets included, and the mean episode length, then (2) the raw
//! `mj_step` rate on the same MJCF, driven by random controls held for `frame_skip`
//! steps and reset as often as the env's random episodes end, and the env-step ceiling
//! it implies (`rate / frame_skip`). The two are timed in alternating rounds and the
//! best round of each is reported, which keeps a shared, loaded machine's noise out of
//! the ratio.
//!
//! ```text
//! source .deps/env.sh && cargo run --release -p ess-envs --example locomotion_speed
//! ```

use std::time::Instant;

use ess_envs::humanoid::HUMANOID_MJCF;
use ess_envs::walker2d::WALKER2D_MJCF;
use ess_envs::{Env, EnvError, Humanoid, HumanoidConfig, Walker2d, Walker2dConfig};
use mujoco_rs::prelude::{MjData, MjModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Env steps timed per round.
const ENV_STEPS: usize = 20_000;
/// Alternating rounds of env and raw timing.
const ROUNDS: usize = 5;

/// Times `ENV_STEPS` random-action steps; returns (steps/s, mean episode length).
fn env_rate(env: &mut dyn Env) -> Result<(f64, f64), EnvError> {
    let spec = env.spec().clone();
    let mut obs = vec![0.0f32; spec.obs_dim];
    let mut act = vec![0.0f32; spec.act_dim];
    let mut rewards = vec![0.0f32; spec.n_modes];
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut episodes = 0u64;
    env.reset(episodes, &mut obs)?;
    let start = Instant::now();
    for _ in 0..ENV_STEPS {
        for a in &mut act {
            *a = rng.random_range(-1.0..=1.0);
        }
        let out = env.step(&act, &mut obs)?;
        env.mode_rewards(&mut rewards);
        if out.done() {
            episodes += 1;
            env.reset(episodes, &mut obs)?;
        }
    }
    let rate = ENV_STEPS as f64 / start.elapsed().as_secs_f64();
    Ok((rate, ENV_STEPS as f64 / episodes.max(1) as f64))
}

/// Raw `mj_step` rate on `xml`, resetting every `reset_every` physics steps.
fn raw_rate(xml: &str, frame_skip: usize, reset_every: usize) -> Result<f64, EnvError> {
    let model = MjModel::from_xml_string(xml).map_err(|e| EnvError::Model {
        reason: e.to_string(),
    })?;
    let mut data = MjData::new(&model);
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let (lo, hi) = (
        model.actuator_ctrlrange()[0][0],
        model.actuator_ctrlrange()[0][1],
    );
    let n = ENV_STEPS * frame_skip;
    let start = Instant::now();
    for i in 0..n {
        if i % reset_every == 0 {
            data.reset();
        }
        if i % frame_skip == 0 {
            for c in data.ctrl_mut() {
                *c = rng.random_range(lo..=hi);
            }
        }
        data.step();
    }
    Ok(n as f64 / start.elapsed().as_secs_f64())
}

fn report(name: &str, env: &mut dyn Env, xml: &str, frame_skip: usize) -> Result<(), EnvError> {
    let (mut rate, mut raw, mut ep_len) = (0.0f64, 0.0f64, 0.0);
    for _ in 0..ROUNDS {
        let (r, len) = env_rate(env)?;
        rate = rate.max(r);
        ep_len = len;
        let reset_every = ((len * frame_skip as f64).round() as usize).max(1);
        raw = raw.max(raw_rate(xml, frame_skip, reset_every)?);
    }
    let ceiling = raw / frame_skip as f64;
    println!(
        "{name}: raw mj_step {raw:.0}/s ({:.2} us) -> ceiling {ceiling:.0} env steps/s at \
         frame_skip {frame_skip}; step (+ mode_rewards, resets) {rate:.0}/s ({:.2} us), \
         {:.0}% of the ceiling; mean random episode {ep_len:.1} steps",
        1e6 / raw,
        1e6 / rate,
        100.0 * rate / ceiling,
    );
    Ok(())
}

fn main() -> Result<(), EnvError> {
    let wcfg = Walker2dConfig::default();
    let skip = wcfg.frame_skip;
    report("walker2d", &mut Walker2d::new(wcfg)?, WALKER2D_MJCF, skip)?;
    let hcfg = HumanoidConfig::default();
    let skip = hcfg.frame_skip;
    report("humanoid", &mut Humanoid::new(hcfg)?, HUMANOID_MJCF, skip)?;
    Ok(())
}
