//! Which rows of a report column seeds can tell apart.
//!
//! A mean over 3-5 seeds ranks the rows of a column, but the first two are often
//! closer than the seeds scatter (Table 1 on Pusher: 0.940 ± 0.022 against 0.902 ±
//! 0.053). Each column's leader is therefore named with the rows an exact two-sided
//! permutation test of the difference of means cannot separate from it at p < 0.05.
//! The permutation test assumes nothing about the distribution of a seed's score (a
//! t-test's normality is not credible at 3-5 seeds with outliers such as a collapsed
//! code), and with few seeds it is exact: every split of the pooled scores into the
//! two groups' sizes is counted. Its floor is worth knowing: at 3 against 3 seeds the
//! smallest two-sided p is 0.1, so nothing separates; at 5 against 5 it is 0.008.

use crate::eval::metrics::mean_std;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

/// The level below which a p-value separates two rows.
pub const ALPHA: f64 = 0.05;

/// Splits counted exactly up to this many pooled scores (2^20 subsets); above it,
/// [`MONTE_CARLO_DRAWS`] random splits.
const EXACT_MAX: usize = 20;
/// Random splits when the pool is too large to enumerate.
const MONTE_CARLO_DRAWS: usize = 100_000;
/// Differences this close to the observed one count as "at least as extreme" (the
/// same split summed in another order).
const TIE: f64 = 1e-12;

/// Two-sided permutation p-value of `mean(a) - mean(b)`: the fraction of the splits of
/// `a ++ b` into groups of `a.len()` and `b.len()` whose difference of means is at least
/// as far from 0 as the observed one. `None` when either group is empty.
pub fn permutation_p(a: &[f64], b: &[f64]) -> Option<f64> {
    if a.is_empty() || b.is_empty() {
        return None;
    }
    let pool: Vec<f64> = a.iter().chain(b).copied().collect();
    let (na, total) = (a.len(), pool.iter().sum::<f64>());
    let diff = |sum_a: f64| sum_a / na as f64 - (total - sum_a) / b.len() as f64;
    let observed = diff(a.iter().sum()).abs();
    let extreme = |sum_a: f64| diff(sum_a).abs() >= observed - TIE;
    if pool.len() <= EXACT_MAX {
        let (mut hits, mut splits) = (0u64, 0u64);
        for mask in 0u32..(1u32 << pool.len()) {
            if mask.count_ones() as usize != na {
                continue;
            }
            let sum_a: f64 = (0..pool.len())
                .filter(|i| mask & (1 << i) != 0)
                .map(|i| pool[i])
                .sum();
            splits += 1;
            hits += u64::from(extreme(sum_a));
        }
        return Some(hits as f64 / splits as f64);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut shuffled = pool.clone();
    let mut hits = 0usize;
    for _ in 0..MONTE_CARLO_DRAWS {
        shuffled.shuffle(&mut rng);
        hits += usize::from(extreme(shuffled[..na].iter().sum()));
    }
    // The observed split counts as one draw, so p is never 0.
    Some((hits + 1) as f64 / (MONTE_CARLO_DRAWS + 1) as f64)
}

/// Whether a larger value of `metric` is better (ENT, the confusion entropy, is the one
/// the paper reads the other way).
pub fn higher_is_better(metric: &str) -> bool {
    metric != "ent"
}

/// The smallest two-sided p an exact permutation test of `na` against `nb` scores can
/// give (all of one group far above all of the other): 1 / C(na + nb, na), or 2 / C
/// when the groups are the same size (the mirrored split is as extreme).
pub fn smallest_p(na: usize, nb: usize) -> f64 {
    let splits = (1..=na.min(nb)).fold(1.0, |c, i| c * (na + nb + 1 - i) as f64 / i as f64);
    let extreme = if na == nb { 2.0 } else { 1.0 };
    (extreme / splits).min(1.0)
}

/// One column's leader and the rows seeds cannot separate from it.
#[derive(Debug, Clone, PartialEq)]
pub struct Leader {
    /// The row with the best mean.
    pub row: String,
    /// Its mean.
    pub mean: f64,
    /// The other rows with p >= [`ALPHA`] against the leader.
    pub tied: Vec<Tied>,
}

/// A row the permutation test cannot separate from the leader.
#[derive(Debug, Clone, PartialEq)]
pub struct Tied {
    /// The row.
    pub row: String,
    /// Its mean.
    pub mean: f64,
    /// Its p against the leader.
    pub p: f64,
    /// [`smallest_p`] at the two rows' seed counts: at [`ALPHA`] or above, no scores
    /// could have separated them.
    pub floor: f64,
}

impl Tied {
    /// Whether the two rows' seed counts could not have separated them whatever the
    /// scores ([`Tied::floor`] at or above [`ALPHA`]).
    pub fn beyond_reach(&self) -> bool {
        self.floor >= ALPHA
    }
}

/// The leader of a column among `rows` (name, scores over seeds; rows without scores
/// are skipped) for `metric`, or `None` when no row has a score.
pub fn leader(metric: &str, rows: &[(String, Vec<f64>)]) -> Option<Leader> {
    let sign = if higher_is_better(metric) { 1.0 } else { -1.0 };
    let scored: Vec<(&String, &[f64], f64)> = rows
        .iter()
        .filter(|(_, xs)| !xs.is_empty())
        .map(|(name, xs)| (name, xs.as_slice(), mean_std(xs).0))
        .collect();
    let &(best, best_xs, best_mean) = scored
        .iter()
        .max_by(|a, b| (sign * a.2).total_cmp(&(sign * b.2)))?;
    let tied = scored
        .iter()
        .filter(|(name, _, _)| *name != best)
        .filter_map(|&(name, xs, mean)| {
            let p = permutation_p(best_xs, xs)?;
            (p >= ALPHA).then(|| Tied {
                row: name.clone(),
                mean,
                p,
                floor: smallest_p(best_xs.len(), xs.len()),
            })
        })
        .collect();
    Some(Leader {
        row: best.clone(),
        mean: best_mean,
        tied,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_p_counts_every_split() {
        // 3 vs 3, fully separated: 2 of the 20 splits are as extreme (this and its mirror).
        let p = permutation_p(&[4.0, 5.0, 6.0], &[1.0, 2.0, 3.0]).unwrap();
        assert!((p - 0.1).abs() < 1e-12, "{p}");
        // 5 vs 5, fully separated: 2 of 252.
        let p = permutation_p(&[6.0, 7.0, 8.0, 9.0, 10.0], &[1.0, 2.0, 3.0, 4.0, 5.0]).unwrap();
        assert!((p - 2.0 / 252.0).abs() < 1e-12, "{p}");
        // Identical groups: every split is at least as extreme.
        assert_eq!(permutation_p(&[1.0, 1.0], &[1.0, 1.0]), Some(1.0));
        assert_eq!(permutation_p(&[], &[1.0]), None);
    }

    #[test]
    fn the_smallest_p_is_that_of_two_fully_separated_groups() {
        for (na, nb) in [(3, 3), (5, 5), (2, 3), (1, 4), (5, 3)] {
            let a: Vec<f64> = (0..na).map(|i| 100.0 + i as f64).collect();
            let b: Vec<f64> = (0..nb).map(|i| i as f64).collect();
            let p = permutation_p(&a, &b).unwrap();
            assert!((smallest_p(na, nb) - p).abs() < 1e-12, "{na} {nb}: {p}");
        }
        assert!((smallest_p(3, 3) - 0.1).abs() < 1e-12);
        assert_eq!(smallest_p(1, 1), 1.0);
    }

    #[test]
    fn exact_p_matches_a_hand_count() {
        // a = [1, 2], b = [3, 4, 6]: observed |1.5 - 4.333| = 2.833. The 10 splits' a-sums
        // (pairs of [1, 2, 3, 4, 6]) are 3, 4, 5, 7, 5, 6, 8, 7, 9, 10, and
        // |sa/2 - (16 - sa)/3| >= 2.833 for sa = 3 (2.833) and sa = 10 (3.0): p = 2/10.
        let p = permutation_p(&[1.0, 2.0], &[3.0, 4.0, 6.0]).unwrap();
        assert!((p - 0.2).abs() < 1e-12, "{p}");
    }

    #[test]
    fn large_pools_fall_back_to_seeded_random_splits() {
        let a: Vec<f64> = (0..11).map(f64::from).collect();
        let b: Vec<f64> = (0..11).map(|i| f64::from(i) + 0.5).collect();
        let p = permutation_p(&a, &b).unwrap();
        assert_eq!(permutation_p(&a, &b), Some(p), "deterministic");
        assert!(p > 0.5, "shifted by a small fraction of the spread: {p}");
        let far: Vec<f64> = b.iter().map(|x| x + 100.0).collect();
        let p = permutation_p(&a, &far).unwrap();
        assert!(p < 1e-4 && p > 0.0, "{p}");
    }

    #[test]
    fn the_leader_names_only_the_rows_seeds_cannot_separate() {
        let rows = vec![
            ("a".to_string(), vec![0.90, 0.92, 0.94, 0.96, 0.98]),
            ("b".to_string(), vec![0.85, 0.95, 0.90, 0.97, 0.80]),
            ("c".to_string(), vec![0.10, 0.12, 0.14, 0.16, 0.18]),
            ("d".to_string(), vec![]),
        ];
        let l = leader("nmi", &rows).unwrap();
        assert_eq!(l.row, "a");
        assert!((l.mean - 0.94).abs() < 1e-12);
        assert_eq!(l.tied.len(), 1, "{l:?}");
        assert_eq!(l.tied[0].row, "b");
        assert!(l.tied[0].p >= 0.05);
        assert!((l.tied[0].floor - 2.0 / 252.0).abs() < 1e-12);
        // ENT: lower is better, so c leads and nothing is near it.
        let l = leader("ent", &rows).unwrap();
        assert_eq!((l.row.as_str(), l.tied.len()), ("c", 0));
        assert_eq!(leader("nmi", &[("x".into(), vec![])]), None);
    }
}
