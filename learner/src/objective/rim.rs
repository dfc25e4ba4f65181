//! Regularized Information Maximization with an approximate label prior, Eq. 8.
//!
//! `L_RIM = -(1/N) sum_i H(Q_c(y | s_i, a_i)) - KL(Q_c(y) || p(c)) - R(psi)`, maximised;
//! Eq. 9 subtracts `lambda_3 L_RIM`, so the learner *minimises*
//! `w_h * mean_i H(Q(.|x_i)) + w_kl * KL(mean_i Q(.|x_i) || p(c)) + w_l2 * ||psi||^2`
//! on unlabeled expert data. The first term is the cluster assumption (confident
//! predictions), the second keeps the empirical label marginal near the learned prior
//! p(c) (which approximates the imbalanced label distribution), the third is L2.
//! p(c) is the target here (detached): it is learned through the policy (Sec. 3.2).

use tch::{Kind, Tensor};

/// The three parts of the RIM loss, each to be minimised.
pub struct RimParts {
    /// Mean conditional entropy `mean_i H(Q(.|x_i))`.
    pub cond_entropy: Tensor,
    /// `KL(mean_i Q(.|x_i) || p(c))`.
    pub marginal_kl: Tensor,
    /// `sum ||psi||^2` over the given parameters.
    pub l2: Tensor,
}

/// Computes the RIM parts from Q_c logits `[n, K]`, prior log-probabilities `[K]`
/// (detached by the caller if wanted) and encoder parameters.
pub fn rim(qc_logits: &Tensor, log_prior: &Tensor, params: &[Tensor]) -> RimParts {
    let logq = qc_logits.log_softmax(-1, Kind::Float);
    let q = logq.exp();
    let cond_entropy = -(&q * &logq)
        .sum_dim_intlist(-1, false, Kind::Float)
        .mean(Kind::Float);
    let marginal = q.mean_dim(0, false, Kind::Float).clamp_min(1e-12);
    let marginal_kl = (&marginal * (marginal.log() - log_prior)).sum(Kind::Float);
    let l2 = params
        .iter()
        .map(|p| p.square().sum(Kind::Float))
        .fold(Tensor::from(0.0f32), |a, b| a + b);
    RimParts {
        cond_entropy,
        marginal_kl,
        l2,
    }
}

impl RimParts {
    /// `w_h * H + w_kl * KL + w_l2 * L2`.
    pub fn weighted(&self, w_h: f64, w_kl: f64, w_l2: f64) -> Tensor {
        &self.cond_entropy * w_h + &self.marginal_kl * w_kl + &self.l2 * w_l2
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::objective::{scalar, t};

    #[test]
    fn confident_predictions_matching_the_prior_cost_nothing() {
        // Two samples, confidently class 0 and class 1; prior uniform over 2.
        let logits = t(&[50.0, -50.0, -50.0, 50.0], 2);
        let log_prior = Tensor::from_slice(&[0.5f32.ln(), 0.5f32.ln()]);
        let r = rim(&logits, &log_prior, &[]);
        assert!(scalar(&r.cond_entropy).abs() < 1e-6);
        assert!(scalar(&r.marginal_kl).abs() < 1e-6);
        assert_eq!(scalar(&r.l2), 0.0);
    }

    #[test]
    fn uniform_predictions_have_entropy_ln_k_and_kl_to_a_skewed_prior() {
        let logits = t(&[0.0; 6], 3);
        let p = [0.5f64, 0.25, 0.25];
        let lp: Vec<f32> = p.iter().map(|x| x.ln() as f32).collect();
        let r = rim(&logits, &Tensor::from_slice(&lp), &[t(&[1.0, 2.0], 1)]);
        assert!((scalar(&r.cond_entropy) - 3f64.ln()).abs() < 1e-6);
        let want_kl: f64 = p
            .iter()
            .map(|pk| (1.0 / 3.0) * ((1.0 / 3.0) / pk).ln())
            .sum();
        assert!((scalar(&r.marginal_kl) - want_kl).abs() < 1e-6);
        assert!((scalar(&r.l2) - 5.0).abs() < 1e-6);
        let w = scalar(&r.weighted(1.0, 2.0, 0.1));
        assert!((w - (3f64.ln() + 2.0 * want_kl + 0.5)).abs() < 1e-5);
    }
}
