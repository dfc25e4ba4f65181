//! One D/Q step and one PPO minibatch step on both backends, at a task's default sizes
//! (the networks `Nets::new` builds for `--env`, D's batch of generated + expert +
//! labeled rows, PPO's minibatch), with the arithmetic rate of each. For profilers and
//! bench/learner.md's per-step table.
//!
//! `cargo run --release -p ess-learner --example fused_profile -- [--env reacher]
//! [--threads 2] [--steps 200] [--only fused|tch] [--phase disc|ppo] [--set key=value]...`

use ess_learner::fused::Fused;
use ess_learner::fused::disc::{DiscDraw, DiscSources};
use ess_learner::objective::combined::{DiscBatch, DiscWeights, disc_objective};
use ess_learner::presets::ConfigLayers;
use ess_learner::train::ppo::PpoBatch;
use ess_learner::train::{Dims, Nets};
use rand::SeedableRng;
use std::time::Instant;
use tch::{Device, Kind, Tensor};

fn arg(name: &str, default: &str) -> String {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
        .unwrap_or_else(|| default.to_string())
}

fn randn(shape: &[i64]) -> Tensor {
    Tensor::randn(shape, (Kind::Float, Device::Cpu))
}

fn idx(n: i64, len: i64) -> Tensor {
    Tensor::randint(n, [len], (Kind::Int64, Device::Cpu))
}

/// Multiply-adds of a forward pass through layers of `sizes`, times two, per row.
fn flop(sizes: &[usize]) -> f64 {
    sizes.windows(2).map(|w| 2.0 * (w[0] * w[1]) as f64).sum()
}

fn main() -> anyhow::Result<()> {
    ess_learner::malloc::keep_freed_memory();
    let env = arg("--env", "reacher");
    let threads: usize = arg("--threads", "2").parse()?;
    let steps: usize = arg("--steps", "200").parse()?;
    let only = arg("--only", "");
    let phase = arg("--phase", "");
    tch::set_num_threads(threads as i32);
    tch::manual_seed(0);
    let set: Vec<String> = std::env::args()
        .collect::<Vec<_>>()
        .windows(2)
        .filter(|w| w[0] == "--set")
        .map(|w| w[1].clone())
        .collect();
    let cfg = ConfigLayers {
        env: Some(env.clone()),
        set,
        ..Default::default()
    }
    .resolve()?;
    let spec = ess_envs::make_plain_env(&cfg.env.name, cfg.env.n_modes)?
        .spec()
        .clone();
    let d = Dims::new(&cfg, &spec.name, spec.obs_dim, spec.act_dim)?;
    let mut nets = Nets::new(&cfg, d)?;
    let mut fused = Fused::new(nets.fused_view(), threads)?;
    let kernels = if std::arch::is_x86_feature_detected!("avx512f") {
        "AVX-512"
    } else {
        "AVX2"
    };
    println!("{env}: {threads} threads, {kernels} kernels");
    let run = Run {
        cfg: &cfg,
        d,
        steps,
        only: &only,
    };
    if phase != "ppo" {
        disc_phase(&run, &mut nets, &mut fused)?;
    }
    if phase != "disc" {
        ppo_phase(&run, &mut nets, &mut fused)?;
    }
    Ok(())
}

/// What both phases read.
struct Run<'a> {
    cfg: &'a ess_proto::CheckedConfig,
    d: Dims,
    steps: usize,
    /// `fused`, `tch` or empty (both).
    only: &'a str,
}

/// Prints one timing: per step, and the arithmetic rate of `f` FLOP a step.
fn report(name: &str, secs: f64, n: usize, f: f64) {
    let per = secs / n as f64;
    println!(
        "  {name:<28} {:8.3} ms  {:7.1} GFLOP/s",
        per * 1e3,
        f / per / 1e9
    );
}

/// The D/Q step on each backend.
fn disc_phase(r: &Run, nets: &mut Nets, fused: &mut Fused) -> anyhow::Result<()> {
    let (cfg, d, steps, only) = (r.cfg, r.d, r.steps, r.only);
    let (inp, k, b) = (d.disc_inp() as i64, d.codes as i64, cfg.disc.batch as i64);
    let w = DiscWeights::at(&cfg.method, 200);
    let labeled = if w.qc_labeled > 0.0 { b } else { 0 };
    let rows = 2 * b + labeled;
    let mut dsizes = vec![inp as usize];
    dsizes.extend(&cfg.disc.hidden);
    dsizes.push(d.codes + 2);
    let dflop =
        3.0 * rows as f64 * flop(&dsizes) - 2.0 * rows as f64 * (inp as usize * dsizes[1]) as f64;
    println!(
        "D {dsizes:?} on {rows} rows ({:.0} MFLOP a step)",
        dflop / 1e6
    );
    let (gx, ex, lx) = (
        randn(&[5000, inp]),
        randn(&[20000, inp]),
        randn(&[2000, inp]),
    );
    let gcode = randn(&[5000, k]).softmax(-1, Kind::Float);
    let geps = randn(&[5000]);
    let (emode, labels) = (idx(k, 20000), idx(k, 2000));
    let lp = Tensor::full([k], -(k as f64).ln(), (Kind::Float, Device::Cpu));
    let lpv: Vec<f32> = Vec::try_from(&lp)?;
    let (gi, ei, li) = (idx(5000, b), idx(20000, b), idx(2000, labeled));
    let (giv, eiv, liv): (Vec<i64>, Vec<i64>, Vec<i64>) = (
        Vec::try_from(&gi)?,
        Vec::try_from(&ei)?,
        Vec::try_from(&li)?,
    );
    if only != "tch" {
        let src = DiscSources {
            gen_x: ess_learner::fused::floats(&gx)?,
            gen_code: ess_learner::fused::floats(&gcode)?,
            gen_eps: ess_learner::fused::floats(&geps)?,
            expert_x: ess_learner::fused::floats(&ex)?,
            expert_mode: ess_learner::fused::longs(&emode)?,
            labeled_x: ess_learner::fused::floats(&lx)?,
            labels: ess_learner::fused::longs(&labels)?,
        };
        let draw = DiscDraw {
            gen_: &giv,
            expert: &eiv,
            labeled: &liv,
            noise: &[],
            instance_noise: &[],
            report: false,
        };
        let mut step = || -> anyhow::Result<()> {
            let mut opt = nets.dopt.flat_mut();
            let (team, net) = (&fused.team, &fused.disc_net);
            fused
                .disc
                .step(team, net, &mut opt, &src, &draw, &w, &lpv)?;
            Ok(())
        };
        for _ in 0..10 {
            step()?;
        }
        let t = Instant::now();
        for _ in 0..steps {
            step()?;
        }
        report("D/Q step, fused", t.elapsed().as_secs_f64(), steps, dflop);
    }
    if only != "fused" {
        let none = idx(1, 0);
        let one = || {
            let batch = DiscBatch {
                gen_x: &gx.index_select(0, &gi),
                gen_code: &gcode.index_select(0, &gi),
                gen_eps: &geps.index_select(0, &gi),
                expert_x: &ex.index_select(0, &ei),
                expert_mode: &none,
                labeled_x: &lx.index_select(0, &li),
                labels: &labels.index_select(0, &li),
            };
            disc_objective(&nets.disc, &batch, &w, &lp)
        };
        for _ in 0..10 {
            let t = one();
            nets.dopt.zero_grad();
            t.loss.backward();
            nets.dopt.step();
        }
        let t0 = Instant::now();
        for _ in 0..steps {
            let t = one();
            nets.dopt.zero_grad();
            t.loss.backward();
            nets.dopt.step();
        }
        report("D/Q step, tch", t0.elapsed().as_secs_f64(), steps, dflop);
    }
    Ok(())
}

/// The PPO minibatch step on each backend.
fn ppo_phase(r: &Run, nets: &mut Nets, fused: &mut Fused) -> anyhow::Result<()> {
    let (cfg, d, steps, only) = (r.cfg, r.d, r.steps, r.only);
    let k = d.codes as i64;
    let n = cfg.ppo.minibatch as i64 * 5;
    let batch = PpoBatch {
        obs: randn(&[n, d.obs as i64]),
        eps: randn(&[n, 1]),
        code: randn(&[n, k]).softmax(-1, Kind::Float),
        gumbel: randn(&[n, k]),
        pre_tanh: randn(&[n, d.act as i64]),
        old_logp: randn(&[n]) - 2.0,
        adv: randn(&[n]),
        returns: randn(&[n]),
    };
    let pin = d.obs + 1 + d.codes;
    let mut psizes = vec![pin];
    psizes.extend(&cfg.ppo.hidden);
    let mut vs = psizes.clone();
    vs.push(1);
    psizes.push(d.act);
    let mb = cfg.ppo.minibatch as f64;
    let pflop =
        3.0 * mb * (flop(&psizes) + flop(&vs)) - 2.0 * mb * (pin * cfg.ppo.hidden[0]) as f64 * 2.0;
    let per_update = cfg.ppo.epochs * 5;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    let updates = (steps / per_update).max(2);
    println!(
        "PPO policy {psizes:?}, value {vs:?}, minibatch {mb} ({:.0} MFLOP a step)",
        pflop / 1e6
    );
    if only != "tch" {
        nets.ppo.update_on(&batch, &mut rng, Some(fused))?;
        let t = Instant::now();
        for _ in 0..updates {
            nets.ppo.update_on(&batch, &mut rng, Some(fused))?;
        }
        report(
            "PPO step, fused",
            t.elapsed().as_secs_f64(),
            updates * per_update,
            pflop,
        );
    }
    if only != "fused" {
        nets.ppo.update(&batch, &mut rng);
        let t = Instant::now();
        for _ in 0..updates {
            nets.ppo.update(&batch, &mut rng);
        }
        report(
            "PPO step, tch",
            t.elapsed().as_secs_f64(),
            updates * per_update,
            pflop,
        );
    }
    Ok(())
}
