//! Behaviour-disentanglement and policy-quality metrics (paper Sec. 4, "Baselines and
//! evaluation metrics"; DESIGN.md "Evaluation").
//!
//! Evaluation rolls out the policy once per one-hot latent code, classifies every
//! generated step with a pre-trained behaviour classifier and accumulates a
//! [`Confusion`] matrix (rows = latent codes, columns = predicted ground-truth classes).
//! From it we compute:
//!
//! - [`nmi`]: normalized mutual information between code and class, with the
//!   arithmetic-mean normalisation `I(U;V) / ((H(U) + H(V)) / 2)`; higher is better.
//! - [`ent`]: the average entropy (ENT) of Elastic-InfoGAN: the mean entropy of each
//!   code's class distribution and of each class's code distribution; lower is better.
//! - [`best_assignment`] / [`assignment_accuracy`]: the optimal one-to-one mapping of
//!   codes to classes (Hungarian algorithm) and the fraction of steps it explains.
//! - [`normalized_reward`]: `(R - R_random) / (R_expert - R_random)` for one mode.
//! - [`mean_std`]: mean and sample standard deviation over seeds.
//!
//! All entropies use the natural logarithm. Every function is total: degenerate
//! inputs (empty matrices, zero counts) give documented finite values, never a panic.

use thiserror::Error;

/// Errors from building or filling a [`Confusion`] matrix.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum MetricsError {
    /// A latent-code index was not below the number of codes.
    #[error("latent code {code} is out of range: the matrix has {n_codes} codes")]
    CodeOutOfRange {
        /// The offending code index.
        code: usize,
        /// Number of codes (rows) of the matrix.
        n_codes: usize,
    },
    /// A class index was not below the number of classes.
    #[error("class {class} is out of range: the matrix has {n_classes} classes")]
    ClassOutOfRange {
        /// The offending class index.
        class: usize,
        /// Number of classes (columns) of the matrix.
        n_classes: usize,
    },
    /// The count vector does not have `n_codes * n_classes` entries.
    #[error("confusion counts have {len} entries, expected {n_codes} codes x {n_classes} classes")]
    ShapeMismatch {
        /// Number of codes (rows) requested.
        n_codes: usize,
        /// Number of classes (columns) requested.
        n_classes: usize,
        /// Length of the count vector that was supplied.
        len: usize,
    },
}

/// Confusion counts: rows = latent codes (`K_c`), columns = predicted ground-truth
/// classes (`K_y`), stored row-major in `counts`.
///
/// The fields are public for cheap inspection; the metric functions stay total even
/// if `counts` is edited to an inconsistent length (missing cells count as zero).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Confusion {
    /// Number of latent codes (rows).
    pub n_codes: usize,
    /// Number of ground-truth classes (columns).
    pub n_classes: usize,
    /// Row-major counts, `counts[code * n_classes + class]`.
    pub counts: Vec<u64>,
}

impl Confusion {
    /// An all-zero `n_codes x n_classes` matrix.
    pub fn new(n_codes: usize, n_classes: usize) -> Self {
        Self {
            n_codes,
            n_classes,
            counts: vec![0; n_codes.saturating_mul(n_classes)],
        }
    }

    /// Counts one step generated under `code` and classified as `class`.
    pub fn add(&mut self, code: usize, class: usize) -> Result<(), MetricsError> {
        if code >= self.n_codes {
            return Err(MetricsError::CodeOutOfRange {
                code,
                n_codes: self.n_codes,
            });
        }
        if class >= self.n_classes {
            return Err(MetricsError::ClassOutOfRange {
                class,
                n_classes: self.n_classes,
            });
        }
        let n_classes = self.n_classes;
        if let Some(cell) = self.counts.get_mut(code * n_classes + class) {
            *cell = cell.saturating_add(1);
        }
        Ok(())
    }

    /// Wraps row-major `counts`; fails unless `counts.len() == n_codes * n_classes`.
    pub fn from_counts(
        n_codes: usize,
        n_classes: usize,
        counts: Vec<u64>,
    ) -> Result<Self, MetricsError> {
        if n_codes.checked_mul(n_classes) != Some(counts.len()) {
            return Err(MetricsError::ShapeMismatch {
                n_codes,
                n_classes,
                len: counts.len(),
            });
        }
        Ok(Self {
            n_codes,
            n_classes,
            counts,
        })
    }

    /// Total number of counted steps (saturating).
    pub fn total(&self) -> u64 {
        self.counts
            .iter()
            .fold(0u64, |acc, &n| acc.saturating_add(n))
    }

    /// The counts of one code over all classes; empty if `code` is out of range.
    pub fn row(&self, code: usize) -> &[u64] {
        let start = code.saturating_mul(self.n_classes);
        self.counts
            .get(start..start.saturating_add(self.n_classes))
            .unwrap_or(&[])
    }

    /// The count of one cell; zero if either index is out of range.
    pub fn count(&self, code: usize, class: usize) -> u64 {
        if code >= self.n_codes || class >= self.n_classes {
            return 0;
        }
        self.counts
            .get(code * self.n_classes + class)
            .copied()
            .unwrap_or(0)
    }

    /// Row sums (steps per code) as `f64`.
    fn row_sums(&self) -> Vec<f64> {
        (0..self.n_codes)
            .map(|i| (0..self.n_classes).map(|j| self.count(i, j) as f64).sum())
            .collect()
    }

    /// Column sums (steps per class) as `f64`.
    fn col_sums(&self) -> Vec<f64> {
        (0..self.n_classes)
            .map(|j| (0..self.n_codes).map(|i| self.count(i, j) as f64).sum())
            .collect()
    }
}

/// Entropy (nats) of the distribution proportional to `weights`; 0 if they sum to 0.
pub(crate) fn entropy<I: IntoIterator<Item = f64> + Clone>(weights: I) -> f64 {
    let total: f64 = weights.clone().into_iter().sum();
    if total <= 0.0 {
        return 0.0;
    }
    let h: f64 = weights
        .into_iter()
        .filter(|&w| w > 0.0)
        .map(|w| {
            let p = w / total;
            -p * p.ln()
        })
        .sum();
    h.max(0.0)
}

/// Normalized mutual information between code `U` and class `V`, arithmetic-mean
/// normalisation: `I(U;V) / ((H(U) + H(V)) / 2)`, natural log, clamped to `[0, 1]`.
///
/// Degenerate cases: an empty matrix, or one with `H(U) + H(V) == 0` (all steps in a
/// single code *and* a single class), returns `0.0`: such a matrix carries no
/// information about disentanglement. (scikit-learn returns 1.0 there; we do not.)
/// If only one of the entropies is 0, `I = 0` and the result is 0 as well.
pub fn nmi(c: &Confusion) -> f64 {
    let n = c.total() as f64;
    if n <= 0.0 {
        return 0.0;
    }
    let rows = c.row_sums();
    let cols = c.col_sums();
    let h_u = entropy(rows.iter().copied());
    let h_v = entropy(cols.iter().copied());
    let denom = (h_u + h_v) / 2.0;
    if denom <= 0.0 {
        return 0.0;
    }
    let mut mi = 0.0;
    for (i, &ri) in rows.iter().enumerate() {
        for (j, &cj) in cols.iter().enumerate() {
            let nij = c.count(i, j) as f64;
            if nij > 0.0 {
                // p_ij ln(p_ij / (p_i p_j)) = (n_ij / N) ln(n_ij N / (n_i n_j)).
                mi += nij / n * (nij * n / (ri * cj)).ln();
            }
        }
    }
    (mi / denom).clamp(0.0, 1.0)
}

/// Average entropy (ENT) as in Elastic-InfoGAN and the paper, natural log.
///
/// `mean_row` is the mean, over codes with at least one count, of the entropy of that
/// code's class distribution (are a code's steps all one class?); `mean_col` is the
/// mean, over classes with at least one count, of the entropy of that class's code
/// distribution (is a class produced by a single code?). `ENT = (mean_row +
/// mean_col) / 2`. A one-to-one matrix gives 0, a uniform `K x K` matrix gives `ln K`;
/// in general `0 <= ENT <= (ln K_y + ln K_c) / 2`. An empty matrix gives 0.
pub fn ent(c: &Confusion) -> f64 {
    let mean_nonempty = |entropies: Vec<(f64, f64)>| -> f64 {
        let used: Vec<f64> = entropies
            .into_iter()
            .filter(|&(sum, _)| sum > 0.0)
            .map(|(_, h)| h)
            .collect();
        if used.is_empty() {
            0.0
        } else {
            used.iter().sum::<f64>() / used.len() as f64
        }
    };
    let row_h: Vec<(f64, f64)> = (0..c.n_codes)
        .map(|i| {
            let w = (0..c.n_classes).map(move |j| c.count(i, j) as f64);
            (w.clone().sum(), entropy(w))
        })
        .collect();
    let col_h: Vec<(f64, f64)> = (0..c.n_classes)
        .map(|j| {
            let w = (0..c.n_codes).map(move |i| c.count(i, j) as f64);
            (w.clone().sum(), entropy(w))
        })
        .collect();
    (mean_nonempty(row_h) + mean_nonempty(col_h)) / 2.0
}

/// Optimal one-to-one assignment code -> class maximising the matched counts
/// (Hungarian algorithm with potentials, `O(n^3)` for `n = max(K_c, K_y)`; rectangular
/// matrices are padded with zero-count dummy rows/columns).
///
/// Returns, for each code, `Some(class)`, or `None` for codes left unmatched because
/// there are more codes than classes. Distinct codes never share a class. Among
/// equally good assignments the choice is deterministic but unspecified.
pub fn best_assignment(c: &Confusion) -> Vec<Option<usize>> {
    let n = c.n_codes.max(c.n_classes);
    if n == 0 {
        return Vec::new();
    }
    // Minimise cost = -count; i128 keeps every sum of u64 counts exact.
    let cost = |i: usize, j: usize| -> i128 { -i128::from(c.count(i, j)) };
    // 1-based arrays as in the classic formulation; index 0 is a virtual row/column.
    let mut u = vec![0i128; n + 1];
    let mut v = vec![0i128; n + 1];
    let mut p = vec![0usize; n + 1]; // p[j] = row matched to column j (0 = none)
    let mut way = vec![0usize; n + 1];
    for i in 1..=n {
        p[0] = i;
        let mut j0 = 0usize;
        let mut minv = vec![i128::MAX; n + 1];
        let mut used = vec![false; n + 1];
        loop {
            used[j0] = true;
            let i0 = p[j0];
            let mut delta = i128::MAX;
            let mut j1 = 0usize;
            for j in 1..=n {
                if used[j] {
                    continue;
                }
                let cur = cost(i0 - 1, j - 1) - u[i0] - v[j];
                if cur < minv[j] {
                    minv[j] = cur;
                    way[j] = j0;
                }
                if minv[j] < delta {
                    delta = minv[j];
                    j1 = j;
                }
            }
            for j in 0..=n {
                if used[j] {
                    u[p[j]] += delta;
                    v[j] -= delta;
                } else {
                    minv[j] -= delta;
                }
            }
            j0 = j1;
            if p[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            p[j0] = p[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    let mut assignment = vec![None; c.n_codes];
    for (j, &row) in p.iter().enumerate().skip(1) {
        let (code, class) = (row.wrapping_sub(1), j - 1);
        if row >= 1 && code < c.n_codes && class < c.n_classes {
            assignment[code] = Some(class);
        }
    }
    assignment
}

/// Normalised task reward of one mode: `(r - r_random) / (r_expert - r_random)`, so a
/// random policy scores 0 and the expert 1. Returns 0.0 if
/// `|r_expert - r_random| < 1e-12` (the reward cannot tell the two apart).
pub fn normalized_reward(r: f64, r_random: f64, r_expert: f64) -> f64 {
    let span = r_expert - r_random;
    if span.abs() < 1e-12 {
        return 0.0;
    }
    (r - r_random) / span
}

/// Accuracy of an assignment: the counts of the assigned `(code, class)` cells divided
/// by the total. Codes beyond `assignment.len()`, `None` entries and out-of-range
/// classes contribute nothing; an empty matrix gives 0.0.
pub fn assignment_accuracy(c: &Confusion, assignment: &[Option<usize>]) -> f64 {
    let total = c.total();
    if total == 0 {
        return 0.0;
    }
    let matched: u64 = assignment
        .iter()
        .enumerate()
        .filter_map(|(code, class)| class.map(|class| c.count(code, class)))
        .fold(0u64, |acc, n| acc.saturating_add(n));
    matched as f64 / total as f64
}

/// Mean and sample standard deviation (`n - 1` denominator) of `xs`.
///
/// The standard deviation is 0.0 for fewer than two values; the mean of an empty
/// slice is NaN (so a missing result cannot masquerade as a real 0).
pub fn mean_std(xs: &[f64]) -> (f64, f64) {
    if xs.is_empty() {
        return (f64::NAN, 0.0);
    }
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    if xs.len() < 2 {
        return (mean, 0.0);
    }
    let ss: f64 = xs.iter().map(|x| (x - mean) * (x - mean)).sum();
    (mean, (ss / (n - 1.0)).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const TOL: f64 = 1e-9;

    fn conf(n_codes: usize, n_classes: usize, counts: &[u64]) -> Confusion {
        Confusion::from_counts(n_codes, n_classes, counts.to_vec()).expect("valid shape")
    }

    fn assert_close(actual: f64, expected: f64) {
        assert!(
            (actual - expected).abs() < TOL,
            "expected {expected}, got {actual}"
        );
    }

    /// `K x K` matrix with `n` steps on cell `(i, perm[i])`.
    fn permutation_matrix(perm: &[usize], n: u64) -> Confusion {
        let k = perm.len();
        let mut c = Confusion::new(k, k);
        for (i, &j) in perm.iter().enumerate() {
            c.counts[i * k + j] = n;
        }
        c
    }

    fn brute_force_best(c: &Confusion) -> u64 {
        fn go(c: &Confusion, code: usize, taken: &mut Vec<bool>) -> u64 {
            if code == c.n_codes {
                return 0;
            }
            // Either leave this code unmatched or give it a free class.
            let mut best = go(c, code + 1, taken);
            for class in 0..c.n_classes {
                if !taken[class] {
                    taken[class] = true;
                    best = best.max(c.count(code, class) + go(c, code + 1, taken));
                    taken[class] = false;
                }
            }
            best
        }
        go(c, 0, &mut vec![false; c.n_classes])
    }

    fn matched(c: &Confusion, a: &[Option<usize>]) -> u64 {
        a.iter()
            .enumerate()
            .filter_map(|(i, j)| j.map(|j| c.count(i, j)))
            .sum()
    }

    fn assert_injective(a: &[Option<usize>]) {
        let mut seen: Vec<usize> = a.iter().flatten().copied().collect();
        let len = seen.len();
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), len, "assignment {a:?} reuses a class");
    }

    #[test]
    fn add_counts_steps_and_rejects_out_of_range_indices() {
        let mut c = Confusion::new(2, 3);
        c.add(1, 2).expect("in range");
        c.add(1, 2).expect("in range");
        c.add(0, 0).expect("in range");
        assert_eq!(c.row(1), &[0, 0, 2]);
        assert_eq!(c.total(), 3);
        assert_eq!(
            c.add(2, 0),
            Err(MetricsError::CodeOutOfRange {
                code: 2,
                n_codes: 2
            })
        );
        assert_eq!(
            c.add(0, 3),
            Err(MetricsError::ClassOutOfRange {
                class: 3,
                n_classes: 3
            })
        );
        assert_eq!(c.total(), 3);
    }

    #[test]
    fn from_counts_rejects_a_vector_of_the_wrong_length() {
        assert_eq!(
            Confusion::from_counts(2, 2, vec![1, 2, 3]),
            Err(MetricsError::ShapeMismatch {
                n_codes: 2,
                n_classes: 2,
                len: 3
            })
        );
    }

    #[test]
    fn row_of_an_out_of_range_code_is_empty() {
        let c = Confusion::new(2, 2);
        assert!(c.row(5).is_empty());
        assert_eq!(c.count(5, 0), 0);
    }

    #[test]
    fn nmi_of_a_perfect_diagonal_is_one_and_ent_is_zero() {
        let c = permutation_matrix(&[0, 1, 2, 3], 50);
        assert_close(nmi(&c), 1.0);
        assert_close(ent(&c), 0.0);
    }

    #[test]
    fn nmi_of_a_permuted_perfect_matrix_is_one() {
        let c = permutation_matrix(&[2, 0, 3, 1], 7);
        assert_close(nmi(&c), 1.0);
        assert_close(ent(&c), 0.0);
    }

    #[test]
    fn best_assignment_recovers_the_permutation_of_a_perfect_matrix() {
        let perm = [2, 0, 3, 1];
        let c = permutation_matrix(&perm, 7);
        let a = best_assignment(&c);
        assert_eq!(a, vec![Some(2), Some(0), Some(3), Some(1)]);
        assert_close(assignment_accuracy(&c, &a), 1.0);
    }

    #[test]
    fn uniform_matrix_has_zero_nmi_and_ent_of_ln_k() {
        for k in 2..6 {
            let c = conf(k, k, &vec![9; k * k]);
            assert_close(nmi(&c), 0.0);
            assert_close(ent(&c), (k as f64).ln());
        }
    }

    #[test]
    fn mode_collapse_onto_one_class_has_zero_nmi_and_ent_of_half_ln_k() {
        // Three codes, all classified as class 0:
        // rows [n,0,0] have entropy 0; the only used column is [n,n,n] with entropy
        // ln 3; ENT = (0 + ln 3) / 2 = 0.5493061443340549. H(V) = 0 so I = 0, NMI = 0.
        let c = conf(3, 3, &[20, 0, 0, 20, 0, 0, 20, 0, 0]);
        assert_close(nmi(&c), 0.0);
        assert_close(ent(&c), 0.549_306_144_334_054_9);
        assert_close(ent(&c), 3f64.ln() / 2.0);
    }

    #[test]
    fn hand_worked_two_by_two_matches_nmi_and_ent() {
        // counts [[4, 0], [2, 2]], N = 8.
        // H(U): rows 4, 4 -> ln 2 = 0.6931471805599453.
        // H(V): cols 6, 2 -> -(3/4 ln 3/4 + 1/4 ln 1/4) = 0.5623351446188083.
        // H(V|U) = 1/2 * 0 + 1/2 * ln 2 = 0.34657359027997264.
        // I = H(V) - H(V|U) = 0.21576155433883565.
        // NMI = I / ((ln 2 + 0.5623351446188083) / 2) = 0.3437110184854508.
        // ENT rows: 0 and ln 2 -> mean 0.34657359027997264.
        // ENT cols: [4, 2] -> ln 3 - 2/3 ln 2 = 0.636514168294813, [0, 2] -> 0;
        //   mean 0.3182570841474065.
        // ENT = (0.34657359027997264 + 0.3182570841474065) / 2 = 0.33241533721368954.
        let c = conf(2, 2, &[4, 0, 2, 2]);
        assert_close(nmi(&c), 0.343_711_018_485_450_8);
        assert_close(ent(&c), 0.332_415_337_213_689_54);
        assert_eq!(best_assignment(&c), vec![Some(0), Some(1)]);
        assert_close(assignment_accuracy(&c, &[Some(0), Some(1)]), 0.75);
    }

    #[test]
    fn rectangular_three_codes_by_two_classes_matches_hand_values() {
        // counts [[5, 0], [0, 5], [5, 5]], N = 20.
        // H(U): rows 5, 5, 10 -> 1.5 ln 2; H(V): cols 10, 10 -> ln 2.
        // I = H(V) - H(V|U) = ln 2 - (1/2) ln 2 = 0.5 ln 2.
        // NMI = 0.5 ln 2 / (1.25 ln 2) = 0.4.
        // ENT rows: 0, 0, ln 2 -> ln 2 / 3; cols: [5,0,5] and [0,5,5] -> ln 2 each.
        // ENT = (ln 2 / 3 + ln 2) / 2 = 2/3 ln 2 = 0.46209812037329684.
        let c = conf(3, 2, &[5, 0, 0, 5, 5, 5]);
        assert_close(nmi(&c), 0.4);
        assert_close(ent(&c), 0.462_098_120_373_296_84);
        let a = best_assignment(&c);
        assert_eq!(a.len(), 3);
        assert_eq!(a.iter().filter(|x| x.is_none()).count(), 1);
        assert_injective(&a);
        assert_close(assignment_accuracy(&c, &a), 0.5);
    }

    #[test]
    fn rectangular_assignment_leaves_the_least_useful_code_unmatched() {
        // Code 2 is worth 9 on class 0; code 1 then takes class 1; code 0 is left out.
        let c = conf(3, 2, &[1, 0, 0, 1, 9, 2]);
        assert_eq!(best_assignment(&c), vec![None, Some(1), Some(0)]);
    }

    #[test]
    fn fewer_codes_than_classes_assigns_every_code() {
        let c = conf(2, 3, &[0, 1, 8, 7, 0, 9]);
        // Options: (2, 0) = 15, (2, 1) = 8, (1, 2) = 10, ... best is code0->2, code1->0.
        assert_eq!(best_assignment(&c), vec![Some(2), Some(0)]);
    }

    #[test]
    fn hungarian_beats_greedy_where_greedy_takes_the_largest_cell_first() {
        // Greedy takes the 10 and is left with 0: total 10. Optimal is 9 + 9 = 18.
        let c = conf(2, 2, &[10, 9, 9, 0]);
        assert_eq!(best_assignment(&c), vec![Some(1), Some(0)]);
        assert_close(assignment_accuracy(&c, &[Some(1), Some(0)]), 18.0 / 28.0);

        // 3x3: greedy takes 5 (0->0), then 0s and 1: total 6. Optimal 4 + 4 + 1 = 9.
        let c = conf(3, 3, &[5, 4, 0, 4, 0, 0, 0, 0, 1]);
        let a = best_assignment(&c);
        assert_eq!(a, vec![Some(1), Some(0), Some(2)]);
        assert_eq!(matched(&c, &a), 9);
    }

    #[test]
    fn empty_and_degenerate_matrices_give_documented_values() {
        let empty = Confusion::new(3, 3);
        assert_eq!(nmi(&empty), 0.0);
        assert_eq!(ent(&empty), 0.0);
        assert_eq!(assignment_accuracy(&empty, &best_assignment(&empty)), 0.0);
        let single = conf(1, 1, &[42]);
        assert_eq!(nmi(&single), 0.0);
        assert_eq!(ent(&single), 0.0);
        let none = Confusion::new(0, 0);
        assert!(best_assignment(&none).is_empty());
        assert_eq!(nmi(&none), 0.0);
    }

    #[test]
    fn normalized_reward_maps_random_to_zero_and_expert_to_one() {
        assert_close(normalized_reward(-3.0, -3.0, 7.0), 0.0);
        assert_close(normalized_reward(7.0, -3.0, 7.0), 1.0);
        assert_close(normalized_reward(2.0, -3.0, 7.0), 0.5);
        assert_close(normalized_reward(-8.0, -3.0, 7.0), -0.5);
        assert_eq!(normalized_reward(5.0, 1.0, 1.0 + 1e-13), 0.0);
    }

    #[test]
    fn mean_std_uses_the_sample_standard_deviation() {
        // 2, 4, 4, 4, 5, 5, 7, 9: mean 5, sum of squares 32, sample var 32 / 7.
        let (m, s) = mean_std(&[2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0]);
        assert_close(m, 5.0);
        assert_close(s, (32.0f64 / 7.0).sqrt());
        assert_eq!(mean_std(&[3.5]), (3.5, 0.0));
        let (m, s) = mean_std(&[]);
        assert!(m.is_nan());
        assert_eq!(s, 0.0);
    }

    fn matrix() -> impl Strategy<Value = Confusion> {
        (1usize..6, 1usize..6).prop_flat_map(|(kc, ky)| {
            proptest::collection::vec(0u64..50, kc * ky)
                .prop_map(move |counts| Confusion::from_counts(kc, ky, counts).expect("shape"))
        })
    }

    /// A matrix together with a row permutation and a column permutation.
    fn matrix_and_perms() -> impl Strategy<Value = (Confusion, Vec<usize>, Vec<usize>)> {
        matrix().prop_flat_map(|c| {
            let rows = Just((0..c.n_codes).collect::<Vec<_>>()).prop_shuffle();
            let cols = Just((0..c.n_classes).collect::<Vec<_>>()).prop_shuffle();
            (Just(c), rows, cols)
        })
    }

    proptest! {
        #[test]
        fn nmi_always_lies_in_the_unit_interval(c in matrix()) {
            let v = nmi(&c);
            prop_assert!((0.0..=1.0).contains(&v), "nmi = {v}");
        }

        #[test]
        fn ent_lies_between_zero_and_the_mean_log_size(c in matrix()) {
            let v = ent(&c);
            let bound = ((c.n_codes as f64).ln() + (c.n_classes as f64).ln()) / 2.0;
            prop_assert!(v >= 0.0 && v <= bound + TOL, "ent = {v}, bound = {bound}");
            let k = c.n_codes.max(c.n_classes) as f64;
            prop_assert!(v <= k.ln() + TOL);
        }

        #[test]
        fn nmi_and_ent_are_invariant_under_row_and_column_permutations(
            (c, rows, cols) in matrix_and_perms()
        ) {
            let mut p = Confusion::new(c.n_codes, c.n_classes);
            for (i, &pi) in rows.iter().enumerate() {
                for (j, &pj) in cols.iter().enumerate() {
                    p.counts[pi * c.n_classes + pj] = c.count(i, j);
                }
            }
            prop_assert!((nmi(&c) - nmi(&p)).abs() < TOL);
            prop_assert!((ent(&c) - ent(&p)).abs() < TOL);
        }

        #[test]
        fn nmi_is_symmetric_under_transposition(c in matrix()) {
            let mut t = Confusion::new(c.n_classes, c.n_codes);
            for i in 0..c.n_codes {
                for j in 0..c.n_classes {
                    t.counts[j * c.n_codes + i] = c.count(i, j);
                }
            }
            prop_assert!((nmi(&c) - nmi(&t)).abs() < TOL);
            prop_assert!((ent(&c) - ent(&t)).abs() < TOL);
        }

        #[test]
        fn best_assignment_is_injective_and_matches_brute_force(c in matrix()) {
            let a = best_assignment(&c);
            prop_assert_eq!(a.len(), c.n_codes);
            assert_injective(&a);
            prop_assert_eq!(a.iter().flatten().count(), c.n_codes.min(c.n_classes));
            prop_assert_eq!(matched(&c, &a), brute_force_best(&c));
        }
    }
}
