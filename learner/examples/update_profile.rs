//! Where one D/Q step and one PPO minibatch step spend their time, at the paper's
//! Reacher sizes (obs 8, act 2, K = 6; D 100-100 on 1000 generated + 1000 expert +
//! 1000 labeled rows; policy and value 64-64 on minibatches of 1000), on the
//! learner's own code (`disc_objective`, `Adam`, `PpoLearner`).
//! `cargo run --release -p ess-learner --example update_profile [threads [disc|ppo]]`.

use ess_learner::objective::combined::{DiscBatch, DiscWeights, disc_objective};
use ess_learner::train::nets::Discriminator;
use ess_learner::train::optim::Adam;
use ess_learner::train::ppo::{PpoBatch, PpoLearner};
use ess_proto::config::{LatentPrior, MethodConfig, PpoConfig};
use rand::SeedableRng;
use std::time::Instant;
use tch::{Kind, Tensor, nn, nn::Module};

const OBS: i64 = 8;
const ACT: i64 = 2;
const K: i64 = 6;
const ROWS: i64 = 1000;

fn randn(shape: &[i64]) -> Tensor {
    Tensor::randn(shape, (Kind::Float, tch::Device::Cpu))
}

fn report(name: &str, total: f64, reps: usize, flop: f64) {
    let per = total / reps as f64;
    let gflops = if flop > 0.0 {
        format!("{:7.1} GFLOP/s", flop / per / 1e9)
    } else {
        String::new()
    };
    println!("{name:<34} {:8.3} ms {gflops}", per * 1e3);
}

fn disc_step(reps: usize) {
    let vs = nn::VarStore::new(tch::Device::Cpu);
    let disc = Discriminator::new(
        vs.root() / "disc",
        (OBS + ACT) as usize,
        &[100, 100],
        K as usize,
    );
    let mut opt = Adam::new(&vs, 3e-4).expect("adam");
    let m = MethodConfig::default();
    let w = DiscWeights::at(&m, 100);
    let (rollout, exp, lab) = (
        randn(&[5000, OBS + ACT]),
        randn(&[20000, OBS + ACT]),
        randn(&[2000, OBS + ACT]),
    );
    let code = randn(&[5000, K]).softmax(-1, Kind::Float);
    let eps = randn(&[5000]);
    let labels = Tensor::randint(K, [2000], (Kind::Int64, tch::Device::Cpu));
    let log_prior = Tensor::full([K], -(K as f64).ln(), (Kind::Float, tch::Device::Cpu));
    let (mut t_idx, mut t_fwd, mut t_bwd, mut t_opt) = (0.0, 0.0, 0.0, 0.0);
    for i in 0..reps + 5 {
        let t0 = Instant::now();
        let gi = Tensor::randint(5000, [ROWS], (Kind::Int64, tch::Device::Cpu));
        let ei = Tensor::randint(20000, [ROWS], (Kind::Int64, tch::Device::Cpu));
        let li = Tensor::randint(2000, [ROWS], (Kind::Int64, tch::Device::Cpu));
        let empty = Tensor::zeros([0], (Kind::Int64, tch::Device::Cpu));
        let b = DiscBatch {
            gen_x: &rollout.index_select(0, &gi),
            gen_code: &code.index_select(0, &gi),
            gen_eps: &eps.index_select(0, &gi),
            expert_x: &exp.index_select(0, &ei),
            expert_mode: &empty,
            labeled_x: &lab.index_select(0, &li),
            labels: &labels.index_select(0, &li),
        };
        let t1 = Instant::now();
        let terms = disc_objective(&disc, &b, &w, &log_prior);
        let _ = f64::try_from(&terms.loss);
        let t2 = Instant::now();
        opt.zero_grad();
        terms.loss.backward();
        let t3 = Instant::now();
        opt.step();
        let t4 = Instant::now();
        if i >= 5 {
            t_idx += (t1 - t0).as_secs_f64();
            t_fwd += (t2 - t1).as_secs_f64();
            t_bwd += (t3 - t2).as_secs_f64();
            t_opt += (t4 - t3).as_secs_f64();
        }
    }
    let x = randn(&[3 * ROWS, OBS + ACT]);
    let t = Instant::now();
    for _ in 0..reps {
        let _ = disc.forward(&x);
    }
    report(
        "  (D forward alone, 3000 rows)",
        t.elapsed().as_secs_f64(),
        reps,
        0.0,
    );
    let t = Instant::now();
    for _ in 0..reps {
        let _ = disc.body.forward(&x);
    }
    report("  (D body alone)", t.elapsed().as_secs_f64(), reps, 0.0);
    let t = Instant::now();
    for _ in 0..reps {
        let _ = tch::no_grad(|| disc.forward(&x));
    }
    report(
        "  (D forward, no_grad)",
        t.elapsed().as_secs_f64(),
        reps,
        0.0,
    );
    let rows = 3.0 * ROWS as f64;
    let layer_flop = |i: f64, o: f64| 2.0 * rows * i * o;
    let fwd = layer_flop((OBS + ACT) as f64, 100.0)
        + layer_flop(100.0, 100.0)
        + layer_flop(100.0, (K + 2) as f64);
    let bwd = 2.0 * fwd - layer_flop((OBS + ACT) as f64, 100.0);
    println!(
        "-- D/Q step ({} rows, {:.0} MFLOP fwd, {:.0} MFLOP bwd)",
        rows,
        fwd / 1e6,
        bwd / 1e6
    );
    report("  index_select (7 sources)", t_idx, reps, 0.0);
    report("  forward + terms", t_fwd, reps, fwd);
    report("  backward", t_bwd, reps, bwd);
    report("  Adam", t_opt, reps, 0.0);
    report("  total", t_idx + t_fwd + t_bwd + t_opt, reps, fwd + bwd);
}

fn ppo_update(reps: usize) {
    let vs = nn::VarStore::new(tch::Device::Cpu);
    let pvs = nn::VarStore::new(tch::Device::Cpu);
    let cfg = PpoConfig {
        epochs: 1,
        ..PpoConfig::default()
    };
    let input = (OBS + 1 + K) as usize;
    let mut ppo = PpoLearner::new(
        &vs,
        &pvs,
        input,
        ACT as usize,
        K as usize,
        &cfg,
        LatentPrior::Gumbel,
        0.1,
    )
    .expect("ppo");
    let n = 5000;
    let b = PpoBatch {
        obs: randn(&[n, OBS]),
        eps: randn(&[n, 1]),
        code: randn(&[n, K]).softmax(-1, Kind::Float),
        gumbel: randn(&[n, K]),
        pre_tanh: randn(&[n, ACT]),
        old_logp: randn(&[n]) - 2.0,
        adv: randn(&[n]),
        returns: randn(&[n]),
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    let _ = ppo.update(&b, &mut rng);
    let t = Instant::now();
    for _ in 0..reps {
        let _ = ppo.update(&b, &mut rng);
    }
    let steps = (reps * (n / ROWS) as usize) as f64;
    let rows = ROWS as f64;
    let net = 2.0 * rows * (input as f64 * 64.0 + 64.0 * 64.0 + 64.0 * ACT as f64);
    let vnet = 2.0 * rows * (input as f64 * 64.0 + 64.0 * 64.0 + 64.0);
    let flop = 3.0 * (net + vnet);
    println!(
        "-- PPO minibatch step ({rows} rows, {:.0} MFLOP fwd+bwd)",
        flop / 1e6
    );
    report("  total", t.elapsed().as_secs_f64(), steps as usize, flop);
}

fn main() {
    ess_learner::malloc::keep_freed_memory();
    let threads: i32 = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(1);
    tch::set_num_threads(threads);
    tch::manual_seed(0);
    println!("libtorch threads: {threads}");
    // A second argument picks one phase: `disc` or `ppo` (for a profiler).
    let only = std::env::args().nth(2).unwrap_or_default();
    if only != "ppo" {
        disc_step(100);
    }
    if only != "disc" {
        ppo_update(if only == "ppo" { 40 } else { 10 });
    }
}
