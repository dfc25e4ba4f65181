//! Contrastive loss of Elastic-InfoGAN, adapted to imitation (the Elastic-InfoGAIL
//! baseline, Sec. 4): a transition and its Gaussian-noise-augmented copy should get the
//! same Q_c prediction (positive pair), while other transitions in the batch are
//! negatives (NT-Xent, as in SimCLR). Applied to unlabeled expert transitions.

use tch::{Kind, Tensor};

/// NT-Xent over `z1[i] <-> z2[i]` positive pairs (`[n, d]` each), cosine similarity,
/// temperature `temp`; mean over the 2n anchors.
pub fn nt_xent(z1: &Tensor, z2: &Tensor, temp: f64) -> Tensor {
    let n = z1.size()[0];
    let z = Tensor::cat(&[z1, z2], 0);
    let norm = z
        .norm_scalaropt_dim(2.0, [-1i64].as_slice(), true)
        .clamp_min(1e-8);
    let z = &z / norm;
    let sim = z.matmul(&z.transpose(0, 1)) / temp;
    // Remove self-similarity from the softmax denominators.
    let eye = Tensor::eye(2 * n, (Kind::Float, z.device())) * 1e9;
    let sim = sim - eye;
    let idx: Vec<i64> = (0..2 * n).map(|i| (i + n) % (2 * n)).collect();
    let targets = Tensor::from_slice(&idx).to_device(z.device());
    sim.log_softmax(-1, Kind::Float).nll_loss(&targets)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::objective::{scalar, t};

    #[test]
    fn aligned_pairs_cost_less_than_swapped_pairs() {
        let a = t(&[1.0, 0.0, 0.0, 1.0], 2);
        let b_aligned = t(&[1.0, 0.1, 0.1, 1.0], 2);
        let b_swapped = t(&[0.1, 1.0, 1.0, 0.1], 2);
        let good = scalar(&nt_xent(&a, &b_aligned, 0.5));
        let bad = scalar(&nt_xent(&a, &b_swapped, 0.5));
        assert!(good < bad, "{good} vs {bad}");
    }

    #[test]
    fn identical_orthogonal_pairs_match_the_closed_form() {
        // z1 = z2 = two orthogonal unit vectors. For anchor i: positive sim 1/T,
        // negatives: the other two vectors with sim 0.  loss = -ln(e^{1/T} / (e^{1/T} + 2)).
        let a = t(&[1.0, 0.0, 0.0, 1.0], 2);
        let temp = 0.5;
        let e = (1.0f64 / temp).exp();
        let want = -(e / (e + 2.0)).ln();
        let v = scalar(&nt_xent(&a, &a, temp));
        assert!((v - want).abs() < 1e-5, "{v} vs {want}");
    }
}
