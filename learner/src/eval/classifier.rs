//! The behaviour classifier of the evaluation protocol (Sec. 4, "we use a pre-trained
//! behavior classifier"): an MLP on `(s', a)` trained on *balanced* expert data to
//! predict the behaviour mode, then used to label every step of the policy's
//! evaluation episodes.

use crate::objective::qc_ce::hard_cross_entropy;
use crate::train::nets::{Mlp, tensor_2d};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tch::{Kind, Tensor, nn, nn::Module, nn::OptimizerConfig};

/// A trained classifier with its input normalisation.
pub struct BehaviourClassifier {
    _vs: nn::VarStore,
    net: Mlp,
    mean: Vec<f32>,
    std: Vec<f32>,
    dim: usize,
}

/// Per-feature mean and std (std floored at 1e-3) of `[n][d]` rows.
pub fn feature_stats(x: &[f32], d: usize) -> (Vec<f32>, Vec<f32>) {
    let n = (x.len() / d.max(1)).max(1) as f64;
    let mut mean = vec![0f64; d];
    let mut sq = vec![0f64; d];
    for row in x.chunks_exact(d) {
        for j in 0..d {
            mean[j] += row[j] as f64;
            sq[j] += (row[j] as f64).powi(2);
        }
    }
    let m: Vec<f32> = mean.iter().map(|s| (s / n) as f32).collect();
    let s: Vec<f32> = sq
        .iter()
        .zip(&mean)
        .map(|(q, s)| ((q / n - (s / n).powi(2)).max(0.0).sqrt() as f32).max(1e-3))
        .collect();
    (m, s)
}

/// Normalises rows in place.
pub fn normalize_rows(x: &mut [f32], mean: &[f32], std: &[f32]) {
    let d = mean.len();
    for row in x.chunks_exact_mut(d) {
        for j in 0..d {
            row[j] = (row[j] - mean[j]) / std[j];
        }
    }
}

impl BehaviourClassifier {
    /// Trains on `[n][dim]` inputs with labels in `0..n_classes`; returns the
    /// classifier and its accuracy on a held-out 20% split.
    pub fn train(
        inputs: &[f32],
        labels: &[i64],
        dim: usize,
        n_classes: usize,
        steps: usize,
        seed: u64,
    ) -> Result<(Self, f64), tch::TchError> {
        let n = labels.len();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut order: Vec<usize> = (0..n).collect();
        rand::seq::SliceRandom::shuffle(order.as_mut_slice(), &mut rng);
        let n_hold = n / 5;
        let (hold, train) = order.split_at(n_hold);
        let (mean, std) = feature_stats(inputs, dim);
        let mut x = inputs.to_vec();
        normalize_rows(&mut x, &mean, &std);
        let gather = |idx: &[usize]| {
            let mut xs = Vec::with_capacity(idx.len() * dim);
            let mut ys = Vec::with_capacity(idx.len());
            for &i in idx {
                xs.extend_from_slice(&x[i * dim..(i + 1) * dim]);
                ys.push(labels[i]);
            }
            (tensor_2d(&xs, dim), Tensor::from_slice(&ys))
        };
        let (xt, yt) = gather(train);
        let (xh, yh) = gather(hold);
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let net = Mlp::new(vs.root() / "cls", &[dim, 64, 64, n_classes], false, 1.0);
        let mut opt = nn::Adam::default().build(&vs, 1e-3)?;
        let nt = train.len() as i64;
        let batch = 256.min(nt.max(1));
        for _ in 0..steps {
            let idx: Vec<i64> = (0..batch).map(|_| rng.random_range(0..nt.max(1))).collect();
            let i = Tensor::from_slice(&idx);
            let loss = hard_cross_entropy(
                &net.forward(&xt.index_select(0, &i)),
                &yt.index_select(0, &i),
            );
            opt.backward_step(&loss);
        }
        let acc = if n_hold > 0 {
            tch::no_grad(|| {
                let pred = net.forward(&xh).argmax(-1, false);
                f64::try_from(pred.eq_tensor(&yh).to_kind(Kind::Float).mean(Kind::Float))
            })?
        } else {
            f64::NAN
        };
        Ok((
            Self {
                _vs: vs,
                net,
                mean,
                std,
                dim,
            },
            acc,
        ))
    }

    /// Predicted class of each `[n][dim]` row.
    pub fn predict(&self, inputs: &[f32]) -> Vec<usize> {
        let mut x = inputs.to_vec();
        normalize_rows(&mut x, &self.mean, &self.std);
        tch::no_grad(|| {
            let pred = self.net.forward(&tensor_2d(&x, self.dim)).argmax(-1, false);
            Vec::<i64>::try_from(&pred)
                .unwrap_or_default()
                .into_iter()
                .map(|p| p as usize)
                .collect()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classifier_separates_two_gaussian_blobs() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut x = Vec::new();
        let mut y = Vec::new();
        for i in 0..400 {
            let c = (i % 2) as i64;
            let centre = if c == 0 { -2.0 } else { 2.0 };
            x.push(centre + rng.random_range(-1.0..1.0f32));
            x.push(rng.random_range(-1.0..1.0f32));
            y.push(c);
        }
        let (cls, acc) = BehaviourClassifier::train(&x, &y, 2, 2, 200, 0).unwrap();
        assert!(acc > 0.95, "held-out accuracy {acc}");
        assert_eq!(cls.predict(&[-2.0, 0.0, 2.0, 0.0]), vec![0, 1]);
    }
}
