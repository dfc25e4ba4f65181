//! Q_c cross-entropy, the semi-supervised regulariser of Eqs. 4-6.
//!
//! - labeled expert data `d^EL` with label `y`: `L_IS^1` (Eq. 4), trained w.r.t. Q_c;
//! - generated data with the sampled code `c` as (soft) target: `L_IS^2` (Eq. 5) /
//!   InfoGAIL's `L_I` (Eq. 2); it reaches the policy through the reward;
//! - all expert data with its true mode (ACGAIL's auxiliary classifier, full labels).
//!
//! Done right: one `log_softmax` of the logits (the reference code applied softmax
//! twice, feeding probabilities into a cross-entropy that softmaxes again).

use tch::{Kind, Tensor};

/// `-mean_i sum_k target_ik log softmax(logits_i)_k`; `target` rows are distributions.
pub fn soft_cross_entropy(logits: &Tensor, target: &Tensor) -> Tensor {
    -(target * logits.log_softmax(-1, Kind::Float))
        .sum_dim_intlist(-1, false, Kind::Float)
        .mean(Kind::Float)
}

/// Cross-entropy with integer class labels `[n]` (i64).
pub fn hard_cross_entropy(logits: &Tensor, labels: &Tensor) -> Tensor {
    logits.log_softmax(-1, Kind::Float).nll_loss(labels)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::objective::{scalar, t};

    #[test]
    fn uniform_logits_cost_ln_k() {
        let logits = t(&[0.0; 8], 4);
        let target = t(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], 4);
        assert!((scalar(&soft_cross_entropy(&logits, &target)) - 4f64.ln()).abs() < 1e-6);
        let labels = Tensor::from_slice(&[0i64, 3]);
        assert!((scalar(&hard_cross_entropy(&logits, &labels)) - 4f64.ln()).abs() < 1e-6);
    }

    #[test]
    fn soft_and_hard_agree_on_one_hot_targets() {
        let logits = t(&[2.0, -1.0, 0.5, 0.0, 1.0, -3.0], 3);
        let target = t(&[0.0, 0.0, 1.0, 0.0, 1.0, 0.0], 3);
        let labels = Tensor::from_slice(&[2i64, 1]);
        let a = scalar(&soft_cross_entropy(&logits, &target));
        let b = scalar(&hard_cross_entropy(&logits, &labels));
        // Row 0: lse(2,-1,.5) - .5; row 1: lse(0,1,-3) - 1.
        let lse = |v: &[f64]| v.iter().map(|x| x.exp()).sum::<f64>().ln();
        let want = ((lse(&[2.0, -1.0, 0.5]) - 0.5) + (lse(&[0.0, 1.0, -3.0]) - 1.0)) / 2.0;
        assert!(
            (a - want).abs() < 1e-6 && (b - want).abs() < 1e-6,
            "{a} {b} {want}"
        );
    }
}
