//! End-to-end env steps/s of a rollout: actor threads in this process against `ess-actor`
//! processes over iceoryx2 shared memory (`bench/transport.md`).
//!
//! ```sh
//! cargo build --release -p ess-actor --bin ess-actor
//! cargo run --release -p ess-learner --example rollout_speed -- traj2d 5000 20
//! cargo run --release -p ess-learner --example rollout_speed -- reacher 5000 10
//! ```
//!
//! Arguments: env (traj2d), steps per rollout (5000), timed rollouts (20), actor counts
//! (1,2). Weights: the default 64-64 policy with small random parameters and a new
//! version per rollout, as in training; no learning happens, so this is the rollout
//! ceiling of each transport.

use anyhow::{Context, Result};
use ess_actor::{LatentSpec, PolicyWeights, RolloutSource, ThreadedActors, Worker};
use ess_learner::actors::{ShmActors, ShmActorsConfig, new_run_id};
use ess_learner::train::actor_seed;
use ess_proto::Mlp;
use ess_proto::config::LatentPrior;
use ess_proto::weights::MlpLayout;
use rand::{Rng, SeedableRng};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn main() -> Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let env = a.get(1).cloned().unwrap_or_else(|| "traj2d".into());
    let steps: usize = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(5000);
    let reps: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(20);
    let counts: Vec<usize> = a
        .get(4)
        .map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect())
        .unwrap_or_else(|| vec![1, 2]);
    // Each env's default mode count (deploy/envs/*.toml).
    let n_modes = match env.as_str() {
        "traj2d" => 4,
        "reacher" => 6,
        _ => 3,
    };
    let spec = ess_envs::make_env(&env, n_modes)?.spec().clone();
    let k = n_modes;
    let latent = LatentSpec {
        prior: LatentPrior::Gumbel,
        n_codes: k,
        tau: 0.1,
        use_eps: true,
    };
    let layout = MlpLayout::new(spec.obs_dim + 1 + k, &[64, 64], spec.act_dim)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    let mut version = 0u64;
    let mut weights = || -> Result<Arc<PolicyWeights>> {
        version += 1;
        let params = (0..layout.n_params())
            .map(|_| rng.random_range(-0.1f32..0.1))
            .collect();
        Ok(Arc::new(PolicyWeights {
            version,
            mean: Mlp::new(layout.clone(), params)?,
            log_std: vec![-0.5; spec.act_dim],
            prior_logits: vec![0.0; k],
            obs_mean: vec![0.0; spec.obs_dim],
            obs_std: vec![1.0; spec.obs_dim],
        }))
    };
    let bin = match std::env::var_os("ESS_ACTOR_BIN") {
        Some(p) => p.into(),
        None => std::env::current_exe()?
            .parent()
            .and_then(|d| d.parent())
            .context("target dir")?
            .join("ess-actor"),
    };
    println!("| env | transport | actors | env steps/s | rollout of {steps} steps |");
    println!("|---|---|---:|---:|---:|");
    for &n in &counts {
        for transport in ["threads", "processes"] {
            let seeds: Vec<u64> = (0..n).map(|i| actor_seed(0, i)).collect();
            let mut src: Box<dyn RolloutSource> = if transport == "threads" {
                let workers = seeds
                    .iter()
                    .map(|&s| Ok(Worker::new(ess_envs::make_env(&env, n_modes)?, s, k)))
                    .collect::<Result<Vec<_>>>()?;
                Box::new(ThreadedActors::new(workers, latent))
            } else {
                Box::new(ShmActors::new(ShmActorsConfig {
                    run_id: new_run_id(),
                    binary: bin.clone(),
                    env: env.clone(),
                    n_modes,
                    latent,
                    seeds,
                    max_steps: steps.div_ceil(n),
                    heartbeat_timeout: Duration::from_secs(3),
                    startup_timeout: Duration::from_secs(30),
                    plain_env: false,
                    task_mode: None,
                })?)
            };
            // Warm-up: process start, env construction, first episodes.
            src.collect(weights()?, steps)?;
            let t = Instant::now();
            for _ in 0..reps {
                let c = src.collect(weights()?, steps)?;
                std::hint::black_box(c);
            }
            let s = t.elapsed().as_secs_f64();
            println!(
                "| {env} | {transport} | {n} | {:.0} | {:.1} ms |",
                (steps * reps) as f64 / s,
                s / reps as f64 * 1e3
            );
        }
    }
    Ok(())
}
