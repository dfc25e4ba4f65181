//! Discriminator binary cross-entropy, the GAIL game of Eq. 1.
//!
//! Convention: `D(s, a) = sigmoid(logit)` is the probability that `(s, a)` comes from the
//! expert. D ascends Eq. 1, i.e. minimises
//! `-E_E[log D] - E_pi[log(1 - D)]`; the policy then descends it through its reward
//! `-log(1 - D)` (see [`super::reward`]).

use tch::{Reduction, Tensor};

/// `BCE(D(expert) = 1 - smoothing) + BCE(D(policy) = policy_target)`, each averaged
/// over its batch (both 0: Eq. 1; else label smoothing, `disc.label_smoothing` and
/// `disc.label_smoothing_policy`).
pub fn disc_bce(
    expert_logit: &Tensor,
    policy_logit: &Tensor,
    smoothing: f64,
    policy_target: f64,
) -> Tensor {
    let expert_t = expert_logit.ones_like() * (1.0 - smoothing);
    let policy_t = policy_logit.ones_like() * policy_target;
    expert_logit.binary_cross_entropy_with_logits::<Tensor>(&expert_t, None, None, Reduction::Mean)
        + policy_logit.binary_cross_entropy_with_logits::<Tensor>(
            &policy_t,
            None,
            None,
            Reduction::Mean,
        )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::objective::scalar;

    #[test]
    fn bce_of_zero_logits_is_two_ln_two() {
        let z = Tensor::from_slice(&[0.0f32, 0.0]);
        let v = scalar(&disc_bce(&z, &z, 0.0, 0.0));
        assert!((v - 2.0 * 2f64.ln()).abs() < 1e-6, "{v}");
    }

    #[test]
    fn bce_matches_hand_computed_values() {
        // expert logit 2 -> -ln(sigmoid(2)); policy logit -1 -> -ln(1 - sigmoid(-1)).
        let e = Tensor::from_slice(&[2.0f32]);
        let p = Tensor::from_slice(&[-1.0f32]);
        let want = (1.0 + (-2f64).exp()).ln() + (1.0 + (-1f64).exp()).ln();
        let v = scalar(&disc_bce(&e, &p, 0.0, 0.0));
        assert!((v - want).abs() < 1e-6, "{v} vs {want}");
    }

    #[test]
    fn a_policy_target_keeps_the_optimal_policy_logit_finite() {
        // BCE(x, t) is smallest at x = logit(t): at t = 0.2, ln(0.25), not -infinity.
        let bce = |x: f32| {
            scalar(&disc_bce(
                &Tensor::from_slice(&[3.0f32]),
                &Tensor::from_slice(&[x]),
                0.0,
                0.2,
            ))
        };
        let best = 0.25f32.ln();
        assert!(bce(best) < bce(best - 0.5) && bce(best) < bce(best + 0.5));
        assert!(bce(-20.0) > bce(best) + 2.0);
    }
}
