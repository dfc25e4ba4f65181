//! The fused backend against tch's autograd: for every preset on every task's default
//! configuration, one D/Q step, one PPO minibatch step and one reward pass from the
//! same weights, Adam moments and batch give the same gradients, Adam-updated weights
//! and moments, reported terms and rewards.
//!
//! "The same" is within 1e-5 relative error per tensor, `|fused - tch| <= 1e-5 |tch|` in
//! the L2 norm over the tensor's elements. Both sides round differently (other
//! summation orders, blocked products, two threads here, tch's tanh as
//! `2 sigmoid(2x) - 1`), so bit equality is not expected, and two kinds of gradient
//! tensor cannot be computed to 1e-5 of themselves in f32 by either side:
//! - a tensor whose gradient nearly cancels over the batch (D's bias at its optimum:
//!   a few 1e-3 from thousands of terms of 5e-4, where one rounding of the sum is
//!   1e-7): its scale is floored at 20% of its network's whole gradient norm (at 5%,
//!   D's output bias measured up to 1.65e-5 on a CPU without AVX-512, AMD EPYC Zen 3,
//!   where libtorch and the `gemm` crate take their AVX2 kernels);
//! - an ill-conditioned step (Elastic-InfoGAIL's NT-Xent with K = 3 near-identical
//!   pairs), where one rounding of the *inputs* alone moves tch's own gradient by more
//!   than 3e-6: the bound is three times that movement (the two forwards differ by a
//!   rounding at each of D's three layers), measured in the test by running tch again
//!   on inputs perturbed by one unit in the last place (`f32::EPSILON` relative).
//!
//! The reported loss values are held to 1e-5 of themselves or 1e-6 absolute (a KL term
//! near 0 is a difference of nearly equal logarithms).
//!
//! `ESS_FUSED_TRACE=1` prints every tensor's error, bound and largest elementwise
//! error.

use super::disc::{DiscDraw, DiscReport, DiscSources};
use super::reward::RewardInputs;
use super::*;
use crate::objective::combined::{
    DiscBatch, DiscTerms, DiscWeights, disc_objective, instance_noise,
};
use crate::objective::reward::{RewardWeights, policy_reward};
use crate::presets::{ConfigLayers, PRESETS};
use crate::train::nets::tensor_to_vec;
use crate::train::ppo::PpoBatch;
use crate::train::{Dims, Nets};
use ess_proto::CheckedConfig;
use rand::SeedableRng;
use tch::{Device, Kind, Tensor};

const ENVS: [&str; 5] = ["traj2d", "reacher", "pusher", "walker2d", "humanoid"];
const REL: f32 = 1e-5;

fn config(env: &str, preset: &str, set: &[&str]) -> CheckedConfig {
    ConfigLayers {
        preset: preset.into(),
        env: Some(env.into()),
        set: set.iter().map(|s| s.to_string()).collect(),
        ..Default::default()
    }
    .resolve()
    .expect("config")
}

fn dims(cfg: &CheckedConfig) -> Dims {
    let env = ess_envs::make_plain_env(&cfg.env.name, cfg.env.n_modes).expect("env");
    let s = env.spec();
    Dims::new(cfg, &s.name, s.obs_dim, s.act_dim).expect("prefix")
}

fn randn(shape: &[i64]) -> Tensor {
    Tensor::randn(shape, (Kind::Float, Device::Cpu))
}

fn idx(n: i64, len: i64) -> Tensor {
    Tensor::randint(n, [len], (Kind::Int64, Device::Cpu))
}

fn norm(x: &[f32]) -> f64 {
    x.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>().sqrt()
}

/// `|got - want| / max(|want|, floor)` in the L2 norm over the tensor.
fn rel_error(got: &[f32], want: &[f32], floor: f64) -> f32 {
    assert_eq!(got.len(), want.len());
    let diff: Vec<f32> = got.iter().zip(want).map(|(g, w)| g - w).collect();
    (norm(&diff) / norm(want).max(floor).max(f64::MIN_POSITIVE)) as f32
}

/// One comparison: what, its relative error, its bound.
type Row = (String, f32, f32);

/// Records `what`'s relative error (scale floored at `floor`) against `bound`.
fn check_with(what: &str, got: &[f32], want: &[f32], floor: f64, bound: f32, rows: &mut Vec<Row>) {
    let e = rel_error(got, want, floor);
    if std::env::var("ESS_FUSED_TRACE").is_ok() {
        let top = want
            .iter()
            .fold(0.0f32, |m, x| m.max(x.abs()))
            .max(f32::MIN_POSITIVE);
        let inf = got
            .iter()
            .zip(want)
            .map(|(g, w)| (g - w).abs())
            .fold(0.0, f32::max)
            / top;
        eprintln!(
            "  {what}: {e:.2e} (bound {bound:.1e}; largest element error / largest element {inf:.2e})"
        );
    }
    rows.push((what.to_string(), e, bound));
}

fn check(what: &str, got: &[f32], want: &[f32], rows: &mut Vec<Row>) {
    check_with(what, got, want, 0.0, REL, rows);
}

/// A network's gradient tensors `(name, offset, values)`.
type Grads = Vec<(String, usize, Vec<f32>)>;

/// Every gradient tensor's error (module docs: the floor and, with `perturbed`, the
/// conditioning bound).
fn check_grads(
    what: &str,
    got: &[f32],
    want: &Grads,
    coef: f32,
    perturbed: Option<&Grads>,
    rows: &mut Vec<Row>,
) {
    let scaled = |w: &[f32]| -> Vec<f32> { w.iter().map(|x| x * coef).collect() };
    let all: Vec<f32> = want.iter().flat_map(|w| scaled(&w.2)).collect();
    let floor = 0.2 * norm(&all);
    for (i, (name, off, w)) in want.iter().enumerate() {
        let w = scaled(w);
        let bound = match perturbed {
            Some(p) => REL.max(3.0 * rel_error(&scaled(&p[i].2), &w, floor)),
            None => REL,
        };
        check_with(
            &format!("{what} gradient {name}"),
            &got[*off..off + w.len()],
            &w,
            floor,
            bound,
            rows,
        );
    }
}

/// Two identical sets of networks and optimisers for `cfg`, with non-trivial weights
/// and Adam moments (a few tch steps on random data), and a p(c) away from uniform.
fn twins(cfg: &CheckedConfig, d: Dims) -> (Nets, Nets) {
    tch::manual_seed(1);
    let mut a = Nets::new(cfg, d).expect("nets");
    tch::no_grad(|| {
        let k = d.codes as i64;
        a.ppo.prior_logits.copy_(&(randn(&[k]) * 0.5));
    });
    let inp = d.disc_inp() as i64;
    let w = DiscWeights::at(&cfg.method, 200);
    let lp = a.ppo.prior_logits.log_softmax(-1, Kind::Float).detach();
    for _ in 0..2 {
        let (x, e, l) = (randn(&[64, inp]), randn(&[64, inp]), randn(&[16, inp]));
        let code = randn(&[64, d.codes as i64]).softmax(-1, Kind::Float);
        let modes = idx(d.codes as i64, 64);
        let labels = idx(d.codes as i64, 16);
        let eps = randn(&[64]);
        let b = DiscBatch {
            gen_x: &x,
            gen_code: &code,
            gen_eps: &eps,
            expert_x: &e,
            expert_mode: &modes,
            labeled_x: &l,
            labels: &labels,
        };
        let t = disc_objective(&a.disc, &b, &w, &lp);
        a.dopt.zero_grad();
        t.loss.backward();
        a.dopt.step();
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    a.ppo.update(&ppo_batch(&a, d, 128), &mut rng);
    tch::manual_seed(1);
    let mut b = Nets::new(cfg, d).expect("nets");
    b.vs.copy(&a.vs).expect("copy");
    b.prior_vs.copy(&a.prior_vs).expect("copy");
    b.dvs.copy(&a.dvs).expect("copy");
    b.dopt.set_state(&a.dopt.state()).expect("state");
    b.ppo.opt.set_state(&a.ppo.opt.state()).expect("state");
    b.ppo
        .prior_opt
        .set_state(&a.ppo.prior_opt.state())
        .expect("state");
    (a, b)
}

/// A rollout batch whose behaviour log-probabilities are near the policy's own, so
/// that some ratios fall inside the clip range and some outside.
fn ppo_batch(nets: &Nets, d: Dims, n: i64) -> PpoBatch {
    let k = d.codes as i64;
    let u = Tensor::rand([n, k], (Kind::Float, Device::Cpu)).clamp(1e-6, 1.0 - 1e-6);
    let gumbel = -(-u.log()).log();
    let obs = randn(&[n, d.obs as i64]);
    let eps = Tensor::rand([n, 1], (Kind::Float, Device::Cpu)) * 2.0 - 1.0;
    let code = randn(&[n, k]).softmax(-1, Kind::Float);
    let input = Tensor::cat(&[&obs, &eps, &code], 1);
    let pre_tanh = randn(&[n, d.act as i64]) * 0.5;
    let old_logp = tch::no_grad(|| nets.ppo.policy.log_prob(&input, &pre_tanh)) + randn(&[n]) * 0.3;
    PpoBatch {
        obs,
        eps,
        code,
        gumbel,
        pre_tanh,
        old_logp,
        adv: randn(&[n]),
        returns: randn(&[n]),
    }
}

/// Every variable's values (or gradients) of `vs` at its offset in `opt`'s buffer.
fn by_offset(
    vs: &tch::nn::VarStore,
    opt: &crate::train::optim::Adam,
    grad: bool,
) -> Vec<(String, usize, Vec<f32>)> {
    let mut v: Vec<_> = vs
        .variables()
        .into_iter()
        .map(|(name, t)| {
            let off = opt.offset_of(&t).expect("offset");
            let vals = if grad {
                tensor_to_vec(&t.grad())
            } else {
                tensor_to_vec(&t)
            };
            (name, off, vals)
        })
        .collect();
    v.sort_by_key(|x| x.1);
    v
}

fn compare_flat(
    what: &str,
    opt_a: &mut crate::train::optim::Adam,
    opt_b: &mut crate::train::optim::Adam,
    worst: &mut Vec<Row>,
) {
    let (a, b) = (opt_a.flat_mut(), opt_b.flat_mut());
    check(
        &format!("{what} weights after Adam"),
        b.params,
        a.params,
        worst,
    );
    check(&format!("{what} exp_avg"), b.exp_avg, a.exp_avg, worst);
    check(
        &format!("{what} exp_avg_sq"),
        b.exp_avg_sq,
        a.exp_avg_sq,
        worst,
    );
    assert_eq!(*a.steps, *b.steps, "{what}: step counts");
}

/// One D/Q step on both backends.
fn disc_step(cfg: &CheckedConfig, d: Dims, a: &mut Nets, b: &mut Nets, worst: &mut Vec<Row>) {
    let inp = d.disc_inp() as i64;
    let (k, batch) = (d.codes as i64, cfg.disc.batch as i64);
    let (gx, ex, lx) = (randn(&[1500, inp]), randn(&[3000, inp]), randn(&[400, inp]));
    let gcode = randn(&[1500, k]).softmax(-1, Kind::Float);
    let geps = Tensor::rand([1500], (Kind::Float, Device::Cpu)) * 2.0 - 1.0;
    let (emode, labels) = (idx(k, 3000), idx(k, 400));
    let w = DiscWeights::at(&cfg.method, 200).with_disc(&cfg.disc);
    let (gi, ei) = (idx(1500, batch), idx(3000, batch));
    let li = if w.qc_labeled > 0.0 {
        idx(400, batch.min(400))
    } else {
        idx(1, 0)
    };
    let lp = a
        .ppo
        .prior_logits
        .log_softmax(-1, Kind::Float)
        .detach()
        .set_requires_grad(true);
    let none = idx(1, 0);
    let mode_rows = if w.qc_full_labels > 0.0 {
        emode.index_select(0, &ei)
    } else {
        none
    };
    // tch's gradient on inputs rounded differently (x (1 + eps N(0, 1))), then on
    // the inputs themselves: the first measures what rounding alone can move.
    let jitter = |x: &Tensor| x * (randn(&x.size()) * f64::from(f32::EPSILON) + 1.0);
    let mut grads = Vec::new();
    let mut terms = None;
    for (gx, ex, lx) in [
        (jitter(&gx), jitter(&ex), jitter(&lx)),
        (gx.shallow_clone(), ex.shallow_clone(), lx.shallow_clone()),
    ] {
        tch::manual_seed(11);
        let t = disc_objective(
            &a.disc,
            &DiscBatch {
                gen_x: &gx.index_select(0, &gi),
                gen_code: &gcode.index_select(0, &gi),
                gen_eps: &geps.index_select(0, &gi),
                expert_x: &ex.index_select(0, &ei),
                expert_mode: &mode_rows,
                labeled_x: &lx.index_select(0, &li),
                labels: &labels.index_select(0, &li),
            },
            &w,
            &lp,
        );
        a.dopt.zero_grad();
        let _ = lp.grad().f_zero_();
        t.loss.backward();
        grads.push(by_offset(&a.dvs, &a.dopt, true));
        terms = Some(t);
    }
    let t = terms.expect("two runs");
    a.dopt.step();
    tch::manual_seed(11);
    let instance = if w.input_noise > 0.0 {
        instance_noise(2 * batch, inp, w.input_noise)
    } else {
        Tensor::zeros([0], (Kind::Float, Device::Cpu))
    };
    let n_con = if w.contrastive > 0.0 {
        w.contrastive_batch.min(batch as usize)
    } else {
        0
    };
    let noise = randn(&[n_con as i64, inp]) * w.contrastive_noise;
    let mut f = Fused::new(b.fused_view(), 2).expect("fused");
    let (gi, ei, li) = (
        Vec::<i64>::try_from(&gi).unwrap(),
        Vec::<i64>::try_from(&ei).unwrap(),
        Vec::<i64>::try_from(&li).unwrap(),
    );
    let src = DiscSources {
        gen_x: floats(&gx).unwrap(),
        gen_code: floats(&gcode).unwrap(),
        gen_eps: floats(&geps).unwrap(),
        expert_x: floats(&ex).unwrap(),
        expert_mode: longs(&emode).unwrap(),
        labeled_x: floats(&lx).unwrap(),
        labels: longs(&labels).unwrap(),
    };
    let draw = DiscDraw {
        gen_: &gi,
        expert: &ei,
        labeled: &li,
        noise: floats(&noise).unwrap(),
        instance_noise: floats(&instance).unwrap(),
        report: true,
    };
    let lpv = tensor_to_vec(&lp);
    let rep = f
        .disc
        .step(
            &f.team,
            &f.disc_net,
            &mut b.dopt.flat_mut(),
            &src,
            &draw,
            &w,
            &lpv,
        )
        .expect("fused step");
    check_grads("D", f.disc.grad(), &grads[1], 1.0, Some(&grads[0]), worst);
    compare_flat("D", &mut a.dopt, &mut b.dopt, worst);
    check_disc_report(&rep, &t, &lp, worst);
}

/// The fused D/Q step's reported terms and p(c) gradient against tch's.
fn check_disc_report(rep: &DiscReport, t: &DiscTerms, lp: &Tensor, worst: &mut Vec<Row>) {
    let scalar = |t: &Tensor| f64::try_from(t).unwrap() as f32;
    let opt = |t: &Option<Tensor>| t.as_ref().map(scalar);
    let pairs = [
        ("BCE", Some(rep.bce as f32), Some(scalar(&t.bce))),
        ("Q_eps MAE", rep.qeps.map(|x| x as f32), opt(&t.qeps)),
        (
            "Q_c CE generated",
            rep.qc_generated.map(|x| x as f32),
            opt(&t.qc_generated),
        ),
        (
            "Q_c CE labeled",
            rep.qc_labeled.map(|x| x as f32),
            opt(&t.qc_labeled),
        ),
        (
            "RIM entropy",
            rep.rim_entropy.map(|x| x as f32),
            opt(&t.rim_entropy),
        ),
        ("RIM KL", rep.rim_kl.map(|x| x as f32), opt(&t.rim_kl)),
        (
            "NT-Xent",
            rep.contrastive.map(|x| x as f32),
            opt(&t.contrastive),
        ),
    ];
    for (what, got, want) in pairs {
        assert_eq!(
            got.is_some(),
            want.is_some(),
            "{what}: present on one side only"
        );
        if let (Some(g), Some(w)) = (got, want) {
            check_with(what, &[g], &[w], 0.1, REL, worst);
        }
    }
    let dlp = lp.grad();
    if dlp.defined() {
        check(
            "d loss / d log p(c)",
            &rep.dlog_prior,
            &tensor_to_vec(&dlp),
            worst,
        );
    } else {
        assert!(
            rep.dlog_prior.iter().all(|&x| x == 0.0),
            "{:?}",
            rep.dlog_prior
        );
    }
}

/// One PPO minibatch step on both backends.
fn ppo_step(d: Dims, a: &mut Nets, b: &mut Nets, worst: &mut Vec<Row>) {
    let n = a.ppo.config().minibatch as i64;
    let batch = ppo_batch(a, d, n);
    let mut ra = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let mut rb = ra.clone();
    let sa = a.ppo.update(&batch, &mut ra);
    let mut f = Fused::new(b.fused_view(), 2).expect("fused");
    let sb = b
        .ppo
        .update_on(&batch, &mut rb, Some(&mut f))
        .expect("fused update");
    let grads = by_offset(&a.vs, &a.ppo.opt, true);
    // tch clips a copy of the gradient; the fused step's gradient is the clipped one.
    let norm = grads
        .iter()
        .flat_map(|g| &g.2)
        .map(|&x| f64::from(x).powi(2))
        .sum::<f64>()
        .sqrt();
    let coef = (a.ppo.config().max_grad_norm / (norm + 1e-6)).min(1.0) as f32;
    check_grads("policy/value", f.ppo.grad(), &grads, coef, None, worst);
    compare_flat("policy/value", &mut a.ppo.opt, &mut b.ppo.opt, worst);
    compare_flat("p(c)", &mut a.ppo.prior_opt, &mut b.ppo.prior_opt, worst);
    for (what, g, w) in [
        ("policy loss", sb.policy_loss, sa.policy_loss),
        ("value loss", sb.value_loss, sa.value_loss),
        ("entropy", sb.entropy, sa.entropy),
        ("approx KL", sb.approx_kl, sa.approx_kl),
    ] {
        check(what, &[g as f32], &[w as f32], worst);
    }
    assert!(
        (sa.clip_frac - sb.clip_frac).abs() < 1e-6,
        "clip fraction {} vs {}",
        sb.clip_frac,
        sa.clip_frac
    );
}

/// The reward pass on both backends.
fn rewards(cfg: &CheckedConfig, d: Dims, b: &mut Nets, worst: &mut Vec<Row>) {
    let n = 700i64;
    let (k, inp) = (d.codes as i64, d.disc_inp() as i64);
    let x = randn(&[n, inp]) * 2.0;
    let code = randn(&[n, k]).softmax(-1, Kind::Float);
    let eps = Tensor::rand([n], (Kind::Float, Device::Cpu)) * 2.0 - 1.0;
    let (obs, next) = (randn(&[n, d.obs as i64]), randn(&[n, d.obs as i64]));
    let prior: Vec<f32> = (0..d.codes).map(|i| (i + 1) as f32).collect();
    let total: f32 = prior.iter().sum();
    let prior: Vec<f32> = prior.iter().map(|p| p / total).collect();
    let rw = RewardWeights::at(&cfg.method, 500, &prior);
    let (want_r, want_v) = tch::no_grad(|| {
        let o = b.disc.forward(&x);
        let r = policy_reward(rw, &o.d_logit, &o.qc_logits, &code, &o.qeps, &eps);
        let e = eps.view([-1, 1]);
        let vin = Tensor::cat(
            &[
                Tensor::cat(&[&obs, &e, &code], 1),
                Tensor::cat(&[&next, &e, &code], 1),
            ],
            0,
        );
        (tensor_to_vec(&r), tensor_to_vec(&b.ppo.values(&vin)))
    });
    let f = Fused::new(b.fused_view(), 2).expect("fused");
    let inputs = RewardInputs {
        disc_x: floats(&x).unwrap(),
        code: floats(&code).unwrap(),
        eps: floats(&eps).unwrap(),
        obs: floats(&obs).unwrap(),
        next_obs: floats(&next).unwrap(),
    };
    let (dp, vp) = (
        b.dopt.flat_mut().params.to_vec(),
        b.ppo.opt.flat_mut().params.to_vec(),
    );
    let mut pass = reward::RewardPass::default();
    let out = pass
        .run(&f.team, &f.disc_net, &dp, &f.policy.value, &vp, &inputs, rw)
        .expect("rewards");
    check("reward", &out.reward, &want_r, worst);
    let mut v = out.values.clone();
    v.extend_from_slice(&out.next_values);
    check("values", &v, &want_v, worst);
}

/// libtorch's generator is one per process and the D/Q steps draw their contrastive
/// noise from it after seeding it: these tests take turns (`make test` runs every
/// test in a process of its own anyway).
static TORCH_RNG: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn run_all(env: &str) {
    run_all_with(env, &[]);
}

/// Every preset on `env` with `set` on top of one PPO epoch.
fn run_all_with(env: &str, set: &[&str]) {
    run_presets_with(env, set, |_| true);
}

/// The presets `keep` accepts (given their config without `set`) on `env`, with `set`
/// on top of one PPO epoch.
fn run_presets_with(env: &str, set: &[&str], keep: impl Fn(&CheckedConfig) -> bool) {
    let _turn = TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner());
    let mut failures = Vec::new();
    for (preset, _) in PRESETS {
        if !keep(&config(env, preset, &[])) {
            continue;
        }
        let cfg = config(env, preset, &[&["ppo.epochs=1"], set].concat());
        let d = dims(&cfg);
        let (mut a, mut b) = twins(&cfg, d);
        let mut worst = Vec::new();
        disc_step(&cfg, d, &mut a, &mut b, &mut worst);
        ppo_step(d, &mut a, &mut b, &mut worst);
        rewards(&cfg, d, &mut b, &mut worst);
        let top = worst
            .iter()
            .cloned()
            .fold(
                ("".to_string(), 0.0f32, 0.0),
                |m, x| if x.1 > m.1 { x } else { m },
            );
        eprintln!(
            "{env} {preset}: largest relative error {:.2e} ({}, bound {:.1e})",
            top.1, top.0, top.2
        );
        failures.extend(
            worst
                .into_iter()
                .filter(|w| w.1.is_nan() || w.1 > w.2)
                .map(|w| format!("{env} {preset} {}: {:.2e} > {:.1e}", w.0, w.1, w.2)),
        );
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn traj2d_every_preset_matches_tch() {
    run_all("traj2d");
}

#[test]
fn reacher_every_preset_matches_tch() {
    run_all("reacher");
}

#[test]
fn pusher_every_preset_matches_tch() {
    run_all("pusher");
}

#[test]
fn walker2d_every_preset_matches_tch() {
    run_all("walker2d");
}

#[test]
fn humanoid_every_preset_matches_tch() {
    run_all("humanoid");
}

#[test]
fn d_regularisers_match_tch() {
    // Label smoothing and instance noise (drawn before the contrastive noise on both).
    run_all_with(
        "reacher",
        &[
            "disc.label_smoothing=0.1",
            "disc.label_smoothing_policy=0.2",
            "disc.input_noise=0.3",
        ],
    );
}

#[test]
fn a_state_only_discriminator_matches_tch() {
    // D, Q_c and Q_eps on the observation alone, with and without an obs prefix.
    run_all_with("humanoid", &["disc.actions=false"]);
    run_all_with("reacher", &["disc.actions=false", "disc.obs_prefix=4"]);
}

#[test]
fn disc_reward_temperature_matches_tch() {
    // Both forms of D's reward term, read at a temperature.
    run_all_with("humanoid", &["method.disc_reward_temperature=7.5"]);
    run_all_with(
        "traj2d",
        &[
            "method.disc_reward_temperature=0.5",
            "method.disc_reward=\"neg-log-one-minus-d\"",
        ],
    );
}

#[test]
fn q_c_floor_value_and_gate_match_tch() {
    // The floor below 0 and D's reward gated by Q_c, on every preset with codes.
    let set = [
        "method.qc_reward_entropy=true",
        "method.qc_reward_floor=true",
        "method.qc_reward_floor_at=-0.5",
        "method.disc_reward_qc_gate=true",
    ];
    run_presets_with("humanoid", &set, |c| {
        c.method.prior != ess_proto::config::LatentPrior::None
    });
}

#[test]
fn r1_is_the_one_setting_left_to_tch() {
    let cfg = config("traj2d", "gail", &["method.w_grad_penalty=1.0"]);
    let why = not_covered(&cfg).expect("not covered");
    assert!(why.contains("w_grad_penalty"), "{why}");
    for env in ENVS {
        for (preset, _) in PRESETS {
            assert_eq!(
                not_covered(&config(env, preset, &[])),
                None,
                "{env} {preset}"
            );
        }
    }
}
