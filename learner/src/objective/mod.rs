//! The one objective of every method, as weighted terms (one file per term).
//!
//! | term | file | paper |
//! |---|---|---|
//! | discriminator BCE | [`disc_bce`] | Eq. 1 |
//! | R1 gradient penalty on D | [`grad_penalty`] | (stabiliser) |
//! | Q_eps regression (MAE) | [`qeps`] | Eq. 2 for eps, Sec. 3.2 |
//! | Q_c cross-entropy (labeled / generated / full labels) | [`qc_ce`] | Eqs. 4-6, ACGAIL |
//! | contrastive NT-Xent on Q_c | [`contrastive`] | Elastic-InfoGAN |
//! | RIM with the p(c) prior | [`rim`] | Eq. 8 |
//! | policy reward | [`reward`] | Eqs. 1, 3, 5, 9 |
//! | the weighted sum of the D/Q terms, and the reward weights | [`combined`] | Eq. 9 |
//!
//! A preset (`deploy/presets/*.toml`) is only a choice of weights and prior; the
//! learner code is the same for all seven methods of Table 1.

pub mod combined;
pub mod contrastive;
pub mod disc_bce;
pub mod grad_penalty;
pub mod qc_ce;
pub mod qeps;
pub mod reward;
pub mod rim;

#[cfg(test)]
pub(crate) fn t(v: &[f32], cols: usize) -> tch::Tensor {
    crate::train::nets::tensor_2d(v, cols)
}

#[cfg(test)]
pub(crate) fn scalar(x: &tch::Tensor) -> f64 {
    f64::try_from(x).unwrap_or(f64::NAN)
}
