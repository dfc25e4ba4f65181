//! Q_eps regression: the mutual information `I(eps; s, a)` of the latent shifting
//! variable, lower-bounded as in Eq. 2 with posterior `Q_psi^eps(eps | s, a)` and trained
//! "as a regression process with the mean absolute error" (Sec. 3.2).

use tch::{Kind, Tensor};

/// `mean |Q_eps(s, a) - eps|` over generated transitions.
pub fn qeps_mae(pred: &Tensor, eps: &Tensor) -> Tensor {
    (pred - eps).abs().mean(Kind::Float)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::objective::scalar;

    #[test]
    fn mae_is_the_mean_absolute_difference() {
        let p = Tensor::from_slice(&[0.5f32, -0.5, 0.0]);
        let e = Tensor::from_slice(&[0.0f32, 0.5, 0.25]);
        assert!((scalar(&qeps_mae(&p, &e)) - 0.5833333).abs() < 1e-6);
    }
}
