//! The policy's reward, the terms of Eq. 9 that depend on the policy:
//!
//! `r(s, a) = w_d * (-log(1 - D(s, a)))            // Eq. 1 (D = P(expert))
//!          + w_c * (sum_k c_k log Q_c(k | s, a) + h_c)  // Eq. 5 / Eq. 2, lambda_2
//!          - w_eps * |Q_eps(s, a) - eps|          // Eq. 2 for eps (MAE), lambda_1`
//!
//! `h_c` is 0, or `H(c)` of the current p(c) so that the term is Eq. 2's bound
//! `L_I = E[log Q(c | tau)] + H(c)` (`method.qc_reward_entropy`).
//!
//! `-log(1 - D) = softplus(logit)`, computed stably. The causal entropy `H(pi)` of
//! Eq. 1 enters through PPO's entropy bonus instead.

use tch::{Kind, Tensor};

/// Weights of the reward terms.
#[derive(Debug, Clone, Copy)]
pub struct RewardWeights {
    /// Use the logit `log D - log(1 - D)` instead of `-log(1 - D)`.
    pub disc_logit: bool,
    /// Discriminator term.
    pub disc: f64,
    /// D's logit is divided by this before the form is applied
    /// (`method.disc_reward_temperature`; 1: the paper's).
    pub disc_temperature: f64,
    /// Latent skill term.
    pub qc: f64,
    /// Constant added to `log Q_c` before weighting (`H(c)`, or 0).
    pub qc_offset: f64,
    /// Multiply the discriminator term by `Q_c(c | s, a)` (`method.disc_reward_qc_gate`).
    pub disc_qc_gate: bool,
    /// Clip `log Q_c + qc_offset` from below at this value (`method.qc_reward_floor`,
    /// at `method.qc_reward_floor_at`); `None`: no clip.
    pub qc_floor: Option<f64>,
    /// Latent shift term.
    pub qeps: f64,
}

/// Per-step rewards `[n]` (no gradient needed: call under `no_grad`).
pub fn policy_reward(
    w: RewardWeights,
    d_logit: &Tensor,
    qc_logits: &Tensor,
    code: &Tensor,
    qeps: &Tensor,
    eps: &Tensor,
) -> Tensor {
    // `sum_k c_k log Q_c(k | s, a)`, computed once for the gate and the information term.
    let log_qc = (w.disc_qc_gate || w.qc != 0.0).then(|| {
        (code * qc_logits.log_softmax(-1, Kind::Float)).sum_dim_intlist(-1, false, Kind::Float)
    });
    let mut r = disc_term(w, d_logit) * w.disc;
    if let Some(lq) = &log_qc {
        if w.disc_qc_gate {
            r *= lq.exp();
        }
        if w.qc != 0.0 {
            let lq = lq + w.qc_offset;
            let lq = match w.qc_floor {
                Some(v) => lq.clamp_min(v),
                None => lq,
            };
            r += lq * w.qc;
        }
    }
    if w.qeps != 0.0 {
        r -= (qeps - eps).abs() * w.qeps;
    }
    r
}

/// The discriminator term alone (unweighted), read at `w.disc_temperature`.
pub fn disc_term(w: RewardWeights, d_logit: &Tensor) -> Tensor {
    let x = d_logit / w.disc_temperature;
    if w.disc_logit { x } else { x.softplus() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::objective::t;

    #[test]
    fn reward_sums_its_three_terms() {
        let w = RewardWeights {
            disc_logit: false,
            disc: 1.0,
            disc_temperature: 1.0,
            qc: 0.5,
            qc_offset: 0.0,
            disc_qc_gate: false,
            qc_floor: None,
            qeps: 2.0,
        };
        let d = Tensor::from_slice(&[0.0f32]);
        let qc = t(&[0.0, 0.0], 2);
        let code = t(&[1.0, 0.0], 2);
        let qe = Tensor::from_slice(&[0.25f32]);
        let eps = Tensor::from_slice(&[-0.25f32]);
        let r =
            f64::try_from(policy_reward(w, &d, &qc, &code, &qe, &eps).sum(Kind::Float)).unwrap();
        let want = 2f64.ln() + 0.5 * 0.5f64.ln() - 2.0 * 0.5;
        assert!((r - want).abs() < 1e-6, "{r} vs {want}");
    }

    #[test]
    fn the_temperature_divides_the_logit_before_the_form() {
        let mut w = RewardWeights {
            disc_logit: false,
            disc: 1.0,
            disc_temperature: 10.0,
            qc: 0.0,
            qc_offset: 0.0,
            disc_qc_gate: false,
            qc_floor: None,
            qeps: 0.0,
        };
        // A sure D (logits -20 and -10): exp-small at T = 1, ln(1 + e^-2) and
        // ln(1 + e^-1) at T = 10.
        let d = Tensor::from_slice(&[-20.0f32, -10.0]);
        let got = |w| Vec::<f32>::try_from(disc_term(w, &d)).unwrap();
        let want = [(1.0 + (-2f32).exp()).ln(), (1.0 + (-1f32).exp()).ln()];
        for (g, w) in got(w).iter().zip(want) {
            assert!((g - w).abs() < 1e-6, "{g} vs {w}");
        }
        w.disc_logit = true;
        assert_eq!(got(w), vec![-2.0, -1.0]);
        w.disc_temperature = 1.0;
        assert_eq!(got(w), vec![-20.0, -10.0]);
    }

    #[test]
    fn entropy_offset_makes_a_chance_level_q_c_reward_zero() {
        // Q_c uniform over 4 codes and H(c) = ln 4: the bound log Q + H(c) is 0.
        let w = RewardWeights {
            disc_logit: true,
            disc: 0.0,
            disc_temperature: 1.0,
            qc: 3.0,
            qc_offset: 4f64.ln(),
            disc_qc_gate: false,
            qc_floor: None,
            qeps: 0.0,
        };
        let d = Tensor::from_slice(&[5.0f32]);
        let qc = t(&[0.3, 0.3, 0.3, 0.3], 4);
        let code = t(&[0.0, 0.0, 1.0, 0.0], 4);
        let e = Tensor::from_slice(&[0.0f32]);
        let r = f64::try_from(policy_reward(w, &d, &qc, &code, &e, &e).sum(Kind::Float)).unwrap();
        assert!(r.abs() < 1e-6, "{r}");
    }

    #[test]
    fn the_floor_leaves_recognised_codes_and_clips_unrecognised_ones_at_its_value() {
        // H(c) = ln 2; Q_c says 0.9 for the first row's code, 0.1 for the second's.
        let mut w = RewardWeights {
            disc_logit: true,
            disc: 0.0,
            disc_temperature: 1.0,
            qc: 1.0,
            qc_offset: 2f64.ln(),
            disc_qc_gate: false,
            qc_floor: Some(0.0),
            qeps: 0.0,
        };
        let d = Tensor::from_slice(&[0.0f32, 0.0]);
        let qc = t(&[0.9f32.ln(), 0.1f32.ln(), 0.9f32.ln(), 0.1f32.ln()], 2);
        let code = t(&[1.0, 0.0, 0.0, 1.0], 2);
        let e = Tensor::from_slice(&[0.0f32, 0.0]);
        let r = |w| Vec::<f32>::try_from(policy_reward(w, &d, &qc, &code, &e, &e)).unwrap();
        let recognised = 0.9f32.ln() + 2f32.ln();
        assert!((r(w)[0] - recognised).abs() < 1e-5, "{:?}", r(w));
        assert_eq!(r(w)[1], 0.0);
        // ln 0.1 + ln 2 = -1.61: a floor at -0.5 charges the step 0.5, none the whole.
        w.qc_floor = Some(-0.5);
        assert!((r(w)[0] - recognised).abs() < 1e-5, "{:?}", r(w));
        assert_eq!(r(w)[1], -0.5);
        w.qc_floor = None;
        assert!(
            (r(w)[1] - (0.1f32.ln() + 2f32.ln())).abs() < 1e-5,
            "{:?}",
            r(w)
        );
    }

    #[test]
    fn the_gate_pays_d_by_how_much_q_c_credits_the_code() {
        // D's logit 2 on both rows; Q_c says 0.9 for the first row's code, 0.1 for
        // the second's; no other term.
        let mut w = RewardWeights {
            disc_logit: true,
            disc: 1.0,
            disc_temperature: 1.0,
            qc: 0.0,
            qc_offset: 0.0,
            disc_qc_gate: true,
            qc_floor: None,
            qeps: 0.0,
        };
        let d = Tensor::from_slice(&[2.0f32, 2.0]);
        let qc = t(&[0.9f32.ln(), 0.1f32.ln(), 0.9f32.ln(), 0.1f32.ln()], 2);
        let code = t(&[1.0, 0.0, 0.0, 1.0], 2);
        let e = Tensor::from_slice(&[0.0f32, 0.0]);
        let r = |w| Vec::<f32>::try_from(policy_reward(w, &d, &qc, &code, &e, &e)).unwrap();
        let got = r(w);
        assert!(
            (got[0] - 1.8).abs() < 1e-5 && (got[1] - 0.2).abs() < 1e-5,
            "{got:?}"
        );
        w.disc_qc_gate = false;
        assert_eq!(r(w), vec![2.0, 2.0]);
    }
}
