//! R1 gradient penalty on the discriminator at expert inputs:
//! `E_E[ ||grad_x logit D(x)||^2 ]`. Not part of the paper's objective; a common GAIL
//! stabiliser, off (weight 0) unless a preset turns it on.

use tch::{Kind, Tensor};

/// Mean squared input-gradient norm of `logit(x)`; `x` must require grad and `logit`
/// must be computed from it.
pub fn r1_penalty(x: &Tensor, logit: &Tensor) -> Tensor {
    let grads = Tensor::run_backward(&[logit.sum(Kind::Float)], &[x], true, true);
    grads[0]
        .square()
        .sum_dim_intlist(-1, false, Kind::Float)
        .mean(Kind::Float)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::objective::{scalar, t};

    #[test]
    fn penalty_of_a_linear_logit_is_its_squared_weight_norm() {
        let x = t(&[1.0, 2.0, 3.0, 4.0], 2).set_requires_grad(true);
        let w = t(&[3.0, -4.0], 1);
        let logit = x.matmul(&w).squeeze_dim(-1);
        let v = scalar(&r1_penalty(&x, &logit));
        assert!((v - 25.0).abs() < 1e-5, "{v}");
    }
}
