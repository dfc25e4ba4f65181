//! The weighted objective of every method, assembled in one place (Eq. 9).
//!
//! The discriminator body and its heads (D, Q_c, Q_eps) minimise
//!
//! `w_disc * BCE (Eq. 1) + w_gp * R1 + w_qeps * MAE(Q_eps) (Eq. 2 for eps)
//!  + w_qc_labeled * CE(Q_c, y) on labeled demos (Eq. 4)
//!  + w_qc_generated * CE(Q_c, c) on rollouts (Eq. 2 / 5)
//!  + w_qc_full * CE(Q_c, mode) on all demos (ACGAIL)
//!  + w_contrastive * NT-Xent (Elastic-InfoGAIL)
//!  + lambda_3(it) * (w_h H + w_kl KL(Q_c || p(c)) + w_l2 ||psi||^2) (Eq. 8)`,
//!
//! and the policy is rewarded with [`RewardWeights::at`]'s weights of Eq. 9's policy
//! terms (see [`super::reward`]). A preset is only a choice of these weights
//! ([`DiscWeights::at`] reads them from `method.*`, with the warm-up schedules).
//!
//! [`disc_objective`] feeds the shared body **one** batch, the rows of every term
//! stacked (`[generated; expert; labeled; noisy expert]`), and slices the heads'
//! outputs: one forward and one backward per step instead of one per data source.

use super::{
    contrastive::nt_xent,
    disc_bce::disc_bce,
    grad_penalty::r1_penalty,
    qc_ce::{hard_cross_entropy, soft_cross_entropy},
    qeps::qeps_mae,
    reward::RewardWeights,
    rim::rim,
};
use crate::train::nets::Discriminator;
use ess_proto::config::{DiscConfig, DiscReward, MethodConfig};
use tch::Tensor;

/// Linear warm-up from 0 to 1 over `iters` iterations (0: always 1).
pub fn warmup(it: usize, iters: usize) -> f64 {
    if iters == 0 {
        1.0
    } else {
        (it as f64 / iters as f64).min(1.0)
    }
}

/// The D/Q side's weights at one iteration (Eq. 9 with the schedules applied).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiscWeights {
    /// Discriminator BCE (Eq. 1).
    pub disc: f64,
    /// R1 gradient penalty on expert inputs.
    pub grad_penalty: f64,
    /// Q_eps MAE on generated data.
    pub qeps: f64,
    /// Q_c cross-entropy on labeled demonstrations (Eq. 4).
    pub qc_labeled: f64,
    /// Q_c cross-entropy on generated data against the sampled code.
    pub qc_generated: f64,
    /// Q_c cross-entropy on all demonstrations against their true mode (ACGAIL).
    pub qc_full_labels: f64,
    /// NT-Xent on noise-augmented expert pairs.
    pub contrastive: f64,
    /// Expert rows that enter the contrastive loss.
    pub contrastive_batch: usize,
    /// Std of the contrastive augmentation noise.
    pub contrastive_noise: f64,
    /// Temperature of the contrastive loss.
    pub contrastive_temperature: f64,
    /// lambda_3 of Eq. 8 after its warm-up.
    pub rim: f64,
    /// RIM's conditional-entropy weight.
    pub rim_cond_entropy: f64,
    /// RIM's marginal-KL weight.
    pub rim_marginal_kl: f64,
    /// RIM's L2 weight on the encoder.
    pub rim_l2: f64,
    /// D's target on expert rows is `1 - label_smoothing` (`disc.label_smoothing`).
    pub label_smoothing: f64,
    /// D's target on generated rows (`disc.label_smoothing_policy`).
    pub policy_target: f64,
    /// Std of the instance noise on generated and expert rows (`disc.input_noise`).
    pub input_noise: f64,
}

impl DiscWeights {
    /// The weights `m` gives at iteration `it` (1-based).
    pub fn at(m: &MethodConfig, it: usize) -> Self {
        Self {
            disc: m.w_disc,
            grad_penalty: m.w_grad_penalty,
            qeps: m.w_qeps,
            qc_labeled: m.w_qc_labeled,
            qc_generated: m.w_qc_generated,
            qc_full_labels: m.w_qc_full_labels,
            contrastive: m.w_contrastive,
            contrastive_batch: m.contrastive_batch,
            contrastive_noise: m.contrastive_noise,
            contrastive_temperature: m.contrastive_temperature,
            rim: m.w_rim * warmup(it, m.rim_warmup_iters),
            rim_cond_entropy: m.rim_cond_entropy,
            rim_marginal_kl: m.rim_marginal_kl,
            rim_l2: m.rim_l2,
            label_smoothing: 0.0,
            policy_target: 0.0,
            input_noise: 0.0,
        }
    }

    /// With D's regularisers of `d` (label smoothing, instance noise).
    pub fn with_disc(self, d: &DiscConfig) -> Self {
        Self {
            label_smoothing: d.label_smoothing,
            policy_target: d.label_smoothing_policy,
            input_noise: d.input_noise,
            ..self
        }
    }
}

impl RewardWeights {
    /// The policy reward's weights `m` gives at iteration `it` (1-based) under the
    /// current p(c) `prior` (its entropy is `h_c` when `method.qc_reward_entropy`).
    pub fn at(m: &MethodConfig, it: usize, prior: &[f32]) -> Self {
        let info = warmup(it, m.info_reward_warmup_iters);
        Self {
            disc_logit: m.disc_reward == DiscReward::Logit,
            disc: m.reward_disc,
            disc_temperature: m.disc_reward_temperature,
            qc: m.reward_qc * info,
            qc_offset: if m.qc_reward_entropy {
                crate::eval::metrics::entropy(prior.iter().map(|&p| f64::from(p)))
            } else {
                0.0
            },
            disc_qc_gate: m.disc_reward_qc_gate,
            qc_floor: m.qc_reward_floor.then_some(m.qc_reward_floor_at),
            qeps: if m.use_eps { m.reward_qeps * info } else { 0.0 },
        }
    }
}

/// One D/Q step's data: rows already normalised and laid out as D reads them.
pub struct DiscBatch<'a> {
    /// Generated inputs `[b, in]`.
    pub gen_x: &'a Tensor,
    /// Their soft codes `[b, K]`.
    pub gen_code: &'a Tensor,
    /// Their eps `[b]`.
    pub gen_eps: &'a Tensor,
    /// Unlabeled expert inputs `[b, in]`.
    pub expert_x: &'a Tensor,
    /// Their true modes `[b]` (used only by the full-label term).
    pub expert_mode: &'a Tensor,
    /// Labeled expert inputs `[l, in]` (`l` may be 0).
    pub labeled_x: &'a Tensor,
    /// Their labels `[l]`.
    pub labels: &'a Tensor,
}

/// The loss to minimise and its parts (each defined only when its weight is not 0).
pub struct DiscTerms {
    /// The weighted sum.
    pub loss: Tensor,
    /// Discriminator BCE.
    pub bce: Tensor,
    /// Q_eps MAE.
    pub qeps: Option<Tensor>,
    /// Q_c CE on generated data.
    pub qc_generated: Option<Tensor>,
    /// Q_c CE on labeled data.
    pub qc_labeled: Option<Tensor>,
    /// RIM conditional entropy.
    pub rim_entropy: Option<Tensor>,
    /// RIM marginal KL.
    pub rim_kl: Option<Tensor>,
    /// NT-Xent.
    pub contrastive: Option<Tensor>,
    /// D logits on the expert rows.
    pub expert_logit: Tensor,
    /// D logits on the generated rows.
    pub policy_logit: Tensor,
    /// Q_c logits on the expert rows.
    pub expert_qc_logits: Tensor,
}

/// Adds `weight * value()` to `loss` and returns the value, computing it only when
/// `weight > 0` (a term switched off costs nothing and is logged as absent).
fn weighted(loss: &mut Tensor, weight: f64, value: impl FnOnce() -> Tensor) -> Option<Tensor> {
    (weight > 0.0).then(|| {
        let v = value();
        *loss += &v * weight;
        v
    })
}

/// `[rows, cols]` of N(0, std^2) from libtorch's generator (D's instance noise).
pub fn instance_noise(rows: i64, cols: i64, std: f64) -> Tensor {
    Tensor::randn([rows, cols], (tch::Kind::Float, tch::Device::Cpu)) * std
}

/// Eq. 9's D/Q side on one batch, in one forward pass of `disc`. `log_prior` is
/// `log p(c)` `[K]`, detached by the caller unless RIM is to move p(c). The
/// contrastive noise is drawn from libtorch's generator.
pub fn disc_objective(
    disc: &Discriminator,
    b: &DiscBatch,
    w: &DiscWeights,
    log_prior: &Tensor,
) -> DiscTerms {
    let n_gen = b.gen_x.size()[0];
    let n_exp = b.expert_x.size()[0];
    let n_lab = if w.qc_labeled > 0.0 {
        b.labeled_x.size()[0]
    } else {
        0
    };
    let expert_x = if w.grad_penalty > 0.0 {
        b.expert_x.detach().set_requires_grad(true)
    } else {
        b.expert_x.shallow_clone()
    };
    // Instance noise first, then the contrastive copies' noise: the fused step draws
    // them from libtorch's generator in the same order.
    let (gen_x, noisy_expert_x) = if w.input_noise > 0.0 {
        let noise = instance_noise(n_gen + n_exp, b.gen_x.size()[1], w.input_noise);
        (
            b.gen_x + noise.narrow(0, 0, n_gen),
            &expert_x + noise.narrow(0, n_gen, n_exp),
        )
    } else {
        (b.gen_x.shallow_clone(), expert_x.shallow_clone())
    };
    let n_con = if w.contrastive > 0.0 {
        (w.contrastive_batch as i64).min(n_exp)
    } else {
        0
    };
    let mut rows = vec![gen_x, noisy_expert_x];
    if n_lab > 0 {
        rows.push(b.labeled_x.shallow_clone());
    }
    if n_con > 0 {
        let xc = b.expert_x.detach().narrow(0, 0, n_con);
        rows.push(&xc + xc.randn_like() * w.contrastive_noise);
    }
    let out = disc.forward(&Tensor::cat(&rows, 0));
    let part = |t: &Tensor, start: i64, len: i64| t.narrow(0, start, len);
    let (og_d, oe_d) = (
        part(&out.d_logit, 0, n_gen),
        part(&out.d_logit, n_gen, n_exp),
    );
    let og_qc = part(&out.qc_logits, 0, n_gen);
    let oe_qc = part(&out.qc_logits, n_gen, n_exp);

    let bce = disc_bce(&oe_d, &og_d, w.label_smoothing, w.policy_target);
    let mut loss = &bce * w.disc;
    if w.grad_penalty > 0.0 {
        loss += r1_penalty(&expert_x, &oe_d) * w.grad_penalty;
    }
    let l = &mut loss;
    let qeps = weighted(l, w.qeps, || {
        qeps_mae(&part(&out.qeps, 0, n_gen), b.gen_eps)
    });
    let qc_generated = weighted(l, w.qc_generated, || soft_cross_entropy(&og_qc, b.gen_code));
    weighted(l, w.qc_full_labels, || {
        hard_cross_entropy(&oe_qc, b.expert_mode)
    });
    let w_lab = if n_lab > 0 { w.qc_labeled } else { 0.0 };
    let qc_labeled = weighted(l, w_lab, || {
        let lab_qc = part(&out.qc_logits, n_gen + n_exp, n_lab);
        hard_cross_entropy(&lab_qc, b.labels)
    });
    let (rim_entropy, rim_kl) = if w.rim > 0.0 {
        let r = rim(&oe_qc, log_prior, &disc.encoder_params());
        *l += r.weighted(w.rim_cond_entropy, w.rim_marginal_kl, w.rim_l2) * w.rim;
        (Some(r.cond_entropy), Some(r.marginal_kl))
    } else {
        (None, None)
    };
    let w_con = if n_con > 0 { w.contrastive } else { 0.0 };
    let contrastive = weighted(l, w_con, || {
        let noisy = part(&out.qc_logits, n_gen + n_exp + n_lab, n_con);
        nt_xent(
            &oe_qc.narrow(0, 0, n_con),
            &noisy,
            w.contrastive_temperature,
        )
    });
    DiscTerms {
        loss,
        bce,
        qeps,
        qc_generated,
        qc_labeled,
        rim_entropy,
        rim_kl,
        contrastive,
        expert_logit: oe_d,
        policy_logit: og_d,
        expert_qc_logits: oe_qc,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::objective::{scalar, t};
    use ess_proto::config::{ConfigBuilder, MethodConfig};
    use tch::{Kind, nn};

    const K: usize = 3;
    const IN: usize = 4;

    /// A discriminator (4 -> 6 -> heads, K = 3) with fixed weights, not libtorch's
    /// random initialisation, so the numbers below depend on nothing else.
    fn fixed_disc() -> (nn::VarStore, Discriminator) {
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let disc = Discriminator::new(vs.root() / "disc", IN, &[6], K);
        let mut vars: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
        vars.sort_by(|a, b| a.0.cmp(&b.0));
        tch::no_grad(|| {
            for (vi, (_, v)) in vars.iter_mut().enumerate() {
                let n = v.numel();
                let vals: Vec<f32> = (0..n)
                    .map(|j| 0.4 * ((1.7 * j as f32) + vi as f32).sin())
                    .collect();
                v.copy_(&Tensor::from_slice(&vals).view(v.size().as_slice()));
            }
        });
        (vs, disc)
    }

    fn rows(n: usize, phase: f32) -> Tensor {
        t(
            &(0..n * IN)
                .map(|i| (0.9 * i as f32 + phase).sin())
                .collect::<Vec<_>>(),
            IN,
        )
    }

    struct Data {
        gen_x: Tensor,
        gen_code: Tensor,
        gen_eps: Tensor,
        expert_x: Tensor,
        expert_mode: Tensor,
        labeled_x: Tensor,
        labels: Tensor,
    }

    fn data() -> Data {
        Data {
            gen_x: rows(5, 0.0),
            gen_code: t(
                &[
                    0.9, 0.05, 0.05, 0.1, 0.8, 0.1, 0.0, 0.0, 1.0, 0.3, 0.3, 0.4, 1.0, 0.0, 0.0,
                ],
                K,
            ),
            gen_eps: Tensor::from_slice(&[0.5f32, -0.25, 0.0, 0.75, -1.0]),
            expert_x: rows(5, 1.3),
            expert_mode: Tensor::from_slice(&[0i64, 1, 2, 0, 1]),
            labeled_x: rows(2, 2.1),
            labels: Tensor::from_slice(&[2i64, 0]),
        }
    }

    fn log_prior() -> Tensor {
        Tensor::from_slice(&[0.5f32, 0.3, 0.2]).log()
    }

    fn objective(disc: &Discriminator, d: &Data, w: &DiscWeights) -> DiscTerms {
        tch::manual_seed(11);
        let b = DiscBatch {
            gen_x: &d.gen_x,
            gen_code: &d.gen_code,
            gen_eps: &d.gen_eps,
            expert_x: &d.expert_x,
            expert_mode: &d.expert_mode,
            labeled_x: &d.labeled_x,
            labels: &d.labels,
        };
        disc_objective(disc, &b, w, &log_prior())
    }

    fn preset_method(name: &str) -> MethodConfig {
        let text = crate::presets::preset(name).expect(name);
        let mut b = ConfigBuilder::new();
        b.merge_toml(name, text).expect(name);
        b.build().expect(name).method.clone()
    }

    #[test]
    fn one_batched_forward_equals_each_term_on_its_own_forward() {
        let (_vs, disc) = fixed_disc();
        let d = data();
        let m = MethodConfig {
            w_grad_penalty: 0.3,
            w_qc_generated: 0.7,
            w_qc_full_labels: 0.4,
            w_contrastive: 0.6,
            contrastive_batch: 3,
            rim_warmup_iters: 4,
            ..MethodConfig::default()
        };
        let w = DiscWeights::at(&m, 2);
        assert_eq!(w.rim, 0.5, "half-way through RIM's warm-up");
        let got = scalar(&objective(&disc, &d, &w).loss);

        tch::manual_seed(11);
        let xc = d.expert_x.narrow(0, 0, 3);
        let noisy = &xc + xc.randn_like() * m.contrastive_noise;
        let xe = d.expert_x.shallow_clone().set_requires_grad(true);
        let (og, oe, ol) = (
            disc.forward(&d.gen_x),
            disc.forward(&xe),
            disc.forward(&d.labeled_x),
        );
        let r = rim(&oe.qc_logits, &log_prior(), &disc.encoder_params());
        let z2 = disc.forward(&noisy).qc_logits;
        let want = disc_bce(&oe.d_logit, &og.d_logit, 0.0, 0.0) * 1.0
            + r1_penalty(&xe, &oe.d_logit) * 0.3
            + qeps_mae(&og.qeps, &d.gen_eps) * 1.0
            + soft_cross_entropy(&og.qc_logits, &d.gen_code) * 0.7
            + hard_cross_entropy(&oe.qc_logits, &d.expert_mode) * 0.4
            + hard_cross_entropy(&ol.qc_logits, &d.labels) * 1.0
            + r.weighted(m.rim_cond_entropy, m.rim_marginal_kl, m.rim_l2) * 0.5
            + nt_xent(
                &oe.qc_logits.narrow(0, 0, 3),
                &z2,
                m.contrastive_temperature,
            ) * 0.6;
        let want = scalar(&want);
        assert!(
            (got - want).abs() < 1e-5 * want.abs().max(1.0),
            "{got} vs {want}"
        );
    }

    /// Each preset's loss on the fixed inputs at iteration 3, and which logged terms it
    /// has (qeps, qc_generated, qc_labeled, rim, contrastive). A change of a preset's
    /// weights, of a term, or of how they are summed shows here.
    const GOLDEN: &[(&str, f64, [bool; 5])] = &[
        ("gail", 1.3829222, [false, false, false, false, false]),
        ("infogail", 2.6372576, [false, true, false, false, false]),
        ("acgail", 4.0575218, [false, true, false, false, false]),
        (
            "elastic-infogail",
            4.7948570,
            [false, true, false, false, true],
        ),
        (
            "ess-infogail-no-gs",
            3.0668037,
            [true, false, true, true, false],
        ),
        (
            "ess-infogail-no-rim",
            2.8691192,
            [true, false, true, false, false],
        ),
        ("ess-infogail", 3.0668037, [true, false, true, true, false]),
    ];

    #[test]
    fn every_preset_weighs_its_terms_as_recorded() {
        let (_vs, disc) = fixed_disc();
        let d = data();
        assert_eq!(GOLDEN.len(), crate::presets::PRESETS.len());
        let mut wrong = Vec::new();
        for &(name, want, has) in GOLDEN {
            let terms = objective(&disc, &d, &DiscWeights::at(&preset_method(name), 3));
            let got = scalar(&terms.loss);
            let present = [
                terms.qeps.is_some(),
                terms.qc_generated.is_some(),
                terms.qc_labeled.is_some(),
                terms.rim_entropy.is_some(),
                terms.contrastive.is_some(),
            ];
            if (got - want).abs() > 1e-5 || present != has {
                wrong.push(format!("(\"{name}\", {got:.7}, {present:?}),"));
            }
        }
        assert!(wrong.is_empty(), "\n{}", wrong.join("\n"));
    }

    /// Each preset's mean policy reward (Eq. 9's policy terms, [`RewardWeights::at`]) on
    /// the fixed generated rows under p(c) = (0.5, 0.3, 0.2), with a 10-iteration
    /// information-reward warm-up: at iteration 3 and after the warm-up.
    const GOLDEN_REWARD: &[(&str, f64, f64)] = &[
        ("gail", -0.0166045, -0.0166045),
        ("infogail", -1.5218071, -5.0339460),
        ("acgail", -1.5218071, -5.0339460),
        ("elastic-infogail", -1.5218071, -5.0339460),
        ("ess-infogail-no-gs", -1.6040967, -5.3082447),
        ("ess-infogail-no-rim", -1.6040967, -5.3082447),
        ("ess-infogail", -1.6040967, -5.3082447),
    ];

    #[test]
    fn every_preset_rewards_the_policy_as_recorded() {
        let (_vs, disc) = fixed_disc();
        let d = data();
        let prior = [0.5f32, 0.3, 0.2];
        let o = tch::no_grad(|| disc.forward(&d.gen_x));
        let mean_reward = |m: &MethodConfig, it: usize| {
            let w = RewardWeights::at(m, it, &prior);
            let r = super::super::reward::policy_reward(
                w,
                &o.d_logit,
                &o.qc_logits,
                &d.gen_code,
                &o.qeps,
                &d.gen_eps,
            );
            scalar(&r.mean(Kind::Float))
        };
        let mut wrong = Vec::new();
        for &(name, early, late) in GOLDEN_REWARD {
            let m = MethodConfig {
                info_reward_warmup_iters: 10,
                ..preset_method(name)
            };
            let got = (mean_reward(&m, 3), mean_reward(&m, 100_000));
            if (got.0 - early).abs() > 1e-5 || (got.1 - late).abs() > 1e-5 {
                wrong.push(format!("(\"{name}\", {:.7}, {:.7}),", got.0, got.1));
            }
        }
        assert!(wrong.is_empty(), "\n{}", wrong.join("\n"));
        // H(c) joins log Q_c when asked: the reward rises by w_c * H(p) per step.
        let m = MethodConfig {
            qc_reward_entropy: true,
            ..MethodConfig::default()
        };
        let plain = MethodConfig::default();
        let h = -(0.5f64 * 0.5f64.ln() + 0.3 * 0.3f64.ln() + 0.2 * 0.2f64.ln());
        let lift = mean_reward(&m, 100_000) - mean_reward(&plain, 100_000);
        assert!((lift - m.reward_qc * h).abs() < 1e-5, "{lift}");
    }
}
