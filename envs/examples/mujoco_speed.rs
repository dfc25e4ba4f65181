//! Single-thread speed of every MuJoCo env (Reacher, Pusher, Walker2d, Humanoid)
//! against its simulation ceiling (`bench/mujoco.md`).
//!
//! For each env it prints (1) the rate of `Env::step` (+ `mode_rewards`) with uniformly
//! random actions, resets included, and the mean episode length; (2) the same loop with
//! the actor's policy forward pass in it (a 64-64 tanh MLP on `[obs, eps, c]`, as
//! `ess train` acts: normalise, forward, Gaussian sample, tanh); then (3) the raw
//! `mj_step` rate on the same MJCF, driven by random controls held for `frame_skip`
//! steps and reset as often as the env's random episodes end, and the env-step ceiling
//! it implies (`rate / frame_skip`). The two are timed in alternating rounds and the
//! best round of each is reported, which keeps a shared, loaded machine's noise out of
//! the ratio.
//!
//! ```text
//! source .deps/env.sh && cargo run --release -p ess-envs --example mujoco_speed
//! ```

use std::time::Instant;

use ess_envs::humanoid::HUMANOID_MJCF;
use ess_envs::pusher::PUSHER_MJCF;
use ess_envs::reacher::REACHER_MJCF;
use ess_envs::walker2d::WALKER2D_MJCF;
use ess_envs::{
    Env, EnvError, Humanoid, HumanoidConfig, Pusher, PusherConfig, Reacher, ReacherConfig,
    Walker2d, Walker2dConfig,
};
use ess_proto::{Mlp, MlpLayout};
use mujoco_rs::prelude::{MjData, MjModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Env steps timed per round.
const ENV_STEPS: usize = 20_000;
/// Alternating rounds of env and raw timing.
const ROUNDS: usize = 5;

/// The actor's acting step: `[norm(obs), eps, c]` through a tanh MLP, a Gaussian
/// sample, tanh. Random small weights: only the cost matters here.
struct PolicyForward {
    mlp: Mlp,
    input: Vec<f32>,
    mean: Vec<f32>,
    scratch: Vec<f32>,
}

impl PolicyForward {
    fn new(obs_dim: usize, n_modes: usize, act_dim: usize) -> Self {
        let layout = MlpLayout {
            sizes: vec![obs_dim + 1 + n_modes, 64, 64, act_dim],
        };
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let params = (0..layout.n_params())
            .map(|_| rng.random_range(-0.1..0.1))
            .collect();
        let mlp = Mlp::new(layout, params).expect("layout fits");
        Self {
            input: vec![0.0; obs_dim + 1 + n_modes],
            mean: vec![0.0; act_dim],
            scratch: vec![0.0; mlp.scratch_len()],
            mlp,
        }
    }

    fn act(&mut self, obs: &[f32], rng: &mut ChaCha8Rng, act: &mut [f32]) {
        for (x, o) in self.input.iter_mut().zip(obs) {
            *x = (o - 0.1) / 1.5;
        }
        self.mlp
            .forward(&self.input, &mut self.mean, &mut self.scratch);
        for (a, m) in act.iter_mut().zip(&self.mean) {
            let n: f32 = rng.sample(StandardNormal);
            *a = (m + 0.6 * n).tanh();
        }
    }
}

/// Times `ENV_STEPS` steps with random actions, or with the policy's when given;
/// returns (steps/s, mean episode length).
fn env_rate(
    env: &mut dyn Env,
    mut policy: Option<&mut PolicyForward>,
) -> Result<(f64, f64), EnvError> {
    let spec = env.spec().clone();
    let mut obs = vec![0.0f32; spec.obs_dim];
    let mut act = vec![0.0f32; spec.act_dim];
    let mut rewards = vec![0.0f32; spec.n_modes];
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut episodes = 0u64;
    env.reset(episodes, &mut obs)?;
    let start = Instant::now();
    for _ in 0..ENV_STEPS {
        match policy.as_deref_mut() {
            Some(p) => p.act(&obs, &mut rng, &mut act),
            None => {
                for a in &mut act {
                    *a = rng.random_range(-1.0..=1.0);
                }
            }
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
    let (mut rate, mut with_policy, mut raw, mut ep_len) = (0.0f64, 0.0f64, 0.0f64, 0.0);
    let spec = env.spec().clone();
    let mut policy = PolicyForward::new(spec.obs_dim, spec.n_modes, spec.act_dim);
    for _ in 0..ROUNDS {
        let (r, len) = env_rate(env, None)?;
        rate = rate.max(r);
        ep_len = len;
        with_policy = with_policy.max(env_rate(env, Some(&mut policy))?.0);
        let reset_every = ((len * frame_skip as f64).round() as usize).max(1);
        raw = raw.max(raw_rate(xml, frame_skip, reset_every)?);
    }
    let ceiling = raw / frame_skip as f64;
    println!(
        "| {name} | {raw:.0} | {frame_skip} | {ceiling:.0} | {rate:.0} ({:.0}%) | {with_policy:.0} ({:.0}%) | {ep_len:.1} |",
        100.0 * rate / ceiling,
        100.0 * with_policy / ceiling,
    );
    Ok(())
}

fn main() -> Result<(), EnvError> {
    println!(
        "| env | raw mj_step/s | frame skip | ceiling env steps/s | env steps/s (% ceiling) | env + policy steps/s (% ceiling) | mean random episode |"
    );
    println!("|---|---|---|---|---|---|---|");
    let rcfg = ReacherConfig::default();
    let skip = rcfg.frame_skip;
    report("reacher", &mut Reacher::new(rcfg)?, REACHER_MJCF, skip)?;
    let pcfg = PusherConfig::default();
    let skip = pcfg.frame_skip;
    report("pusher", &mut Pusher::new(pcfg)?, PUSHER_MJCF, skip)?;
    let wcfg = Walker2dConfig::default();
    let skip = wcfg.frame_skip;
    report("walker2d", &mut Walker2d::new(wcfg)?, WALKER2D_MJCF, skip)?;
    let hcfg = HumanoidConfig::default();
    let skip = hcfg.frame_skip;
    report("humanoid", &mut Humanoid::new(hcfg)?, HUMANOID_MJCF, skip)?;
    Ok(())
}
