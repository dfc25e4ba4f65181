//! Pure-Rust forward pass of a tanh MLP from flat `f32` weights ([`MlpLayout`]).
//!
//! Actors never link libtorch: the policy is small, and a plain loop over the weights
//! (as the learner exports them, `torch.nn.Linear` layout) has no per-call overhead.
//! The learner's tests hold this forward equal to the tch one within 1e-5. It lives
//! here, beside [`MlpLayout`], because both the actors (imitation policy) and `envs`
//! (trained expert policies that generate demonstrations) evaluate such weights.

use crate::weights::{MlpLayout, WeightsError};

/// A tanh MLP with its flat parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Mlp {
    layout: MlpLayout,
    params: Vec<f32>,
}

impl Mlp {
    /// Wraps `params`, checked against `layout`.
    pub fn new(layout: MlpLayout, params: Vec<f32>) -> Result<Self, WeightsError> {
        layout.check(&params)?;
        Ok(Self { layout, params })
    }

    /// The layout.
    pub fn layout(&self) -> &MlpLayout {
        &self.layout
    }

    /// The flat parameters.
    pub fn params(&self) -> &[f32] {
        &self.params
    }

    /// Scratch floats [`Mlp::forward`] needs.
    pub fn scratch_len(&self) -> usize {
        2 * self.layout.max_width()
    }

    /// Computes the output for one input row. `input.len()` must be the layout's input
    /// width, `out.len()` its output width, `scratch.len() >= scratch_len()`.
    pub fn forward(&self, input: &[f32], out: &mut [f32], scratch: &mut [f32]) {
        let sizes = &self.layout.sizes;
        let w = self.layout.max_width();
        let (a, b) = scratch.split_at_mut(w);
        a[..input.len()].copy_from_slice(input);
        let (mut cur, mut nxt) = (a, b);
        let n = sizes.len() - 1;
        for l in 0..n {
            let (n_in, n_out) = (sizes[l], sizes[l + 1]);
            let (wo, bo) = self.layout.offsets(l);
            let weights = &self.params[wo..bo];
            let bias = &self.params[bo..bo + n_out];
            let x = &cur[..n_in];
            for (o, (row, bias_o)) in weights.chunks_exact(n_in).zip(bias).enumerate() {
                let mut acc = *bias_o;
                for (wi, xi) in row.iter().zip(x) {
                    acc += wi * xi;
                }
                nxt[o] = if l + 1 < n { acc.tanh() } else { acc };
            }
            std::mem::swap(&mut cur, &mut nxt);
        }
        out.copy_from_slice(&cur[..sizes[n]]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_matches_a_hand_computed_two_layer_net() {
        // in 2 -> hidden 2 (tanh) -> out 1
        let layout = MlpLayout::new(2, &[2], 1).unwrap();
        #[rustfmt::skip]
        let params = vec![
            0.5, -1.0,   // W0 row 0
            2.0, 0.25,   // W0 row 1
            0.1, -0.2,   // b0
            1.5, -0.5,   // W1
            0.3,         // b1
        ];
        let mlp = Mlp::new(layout, params).unwrap();
        let x = [0.2f32, -0.4];
        let h0 = (0.5f32 * 0.2 + -1.0 * -0.4 + 0.1).tanh();
        let h1 = (2.0f32 * 0.2 + 0.25 * -0.4 - 0.2).tanh();
        let y = 1.5 * h0 - 0.5 * h1 + 0.3;
        let mut out = [0.0f32];
        let mut scratch = vec![0.0; mlp.scratch_len()];
        mlp.forward(&x, &mut out, &mut scratch);
        assert!((out[0] - y).abs() < 1e-6, "{} vs {y}", out[0]);
    }
}
