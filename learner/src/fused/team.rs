//! Threads over the batch: a step's rows are cut into one contiguous block per thread,
//! and each thread runs the whole forward (or backward) pass of its block on its own
//! buffers, so a step has two meeting points (after the forward and after the backward
//! pass) instead of one per layer. Block 0 runs on the calling thread, the others on
//! the team's threads (`rayon-core`, kept between steps).

use std::sync::Mutex;

/// The learner's worker threads.
pub struct Team {
    pool: Option<rayon_core::ThreadPool>,
    threads: usize,
}

/// The team's threads could not be started.
#[derive(Debug, thiserror::Error)]
#[error("starting {threads} learner threads: {source}")]
pub struct TeamError {
    threads: usize,
    source: rayon_core::ThreadPoolBuildError,
}

impl Team {
    /// A team of `threads` (at least 1: the calling thread alone).
    pub fn new(threads: usize) -> Result<Self, TeamError> {
        let threads = threads.max(1);
        let pool = if threads > 1 {
            let p = rayon_core::ThreadPoolBuilder::new()
                .num_threads(threads - 1)
                .thread_name(|i| format!("ess-learner-{}", i + 1))
                .build()
                .map_err(|source| TeamError { threads, source })?;
            Some(p)
        } else {
            None
        };
        Ok(Self { pool, threads })
    }

    /// Threads, the calling one included.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Runs `f(i, &mut items[i])` for every item, item 0 on the calling thread and the
    /// others on the team's threads, and returns when all are done: the first error
    /// any of them returned, if any.
    pub fn each<T: Send, E: Send>(
        &self,
        items: &mut [T],
        f: impl Fn(usize, &mut T) -> Result<(), E> + Sync,
    ) -> Result<(), E> {
        let Some((first, rest)) = items.split_first_mut() else {
            return Ok(());
        };
        let pool = match &self.pool {
            Some(p) if !rest.is_empty() => p,
            _ => {
                f(0, first)?;
                for (i, it) in rest.iter_mut().enumerate() {
                    f(i + 1, it)?;
                }
                return Ok(());
            }
        };
        let failed: Mutex<Option<E>> = Mutex::new(None);
        let record = |r: Result<(), E>| {
            if let Err(e) = r
                && let Ok(mut slot) = failed.lock()
            {
                slot.get_or_insert(e);
            }
        };
        pool.in_place_scope(|s| {
            for (i, it) in rest.iter_mut().enumerate() {
                let (f, record) = (&f, &record);
                s.spawn(move |_| record(f(i + 1, it)));
            }
            record(f(0, first));
        });
        match failed.into_inner() {
            Ok(Some(e)) => Err(e),
            _ => Ok(()),
        }
    }
}

/// The rows `[start, end)` of block `i` when `n` rows are cut into `blocks` blocks as
/// evenly as possible (the first `n % blocks` one row longer).
pub fn block(n: usize, blocks: usize, i: usize) -> (usize, usize) {
    let blocks = blocks.max(1);
    let (base, extra) = (n / blocks, n % blocks);
    let start = i * base + i.min(extra);
    (start, start + base + usize::from(i < extra))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_cover_every_row_once_and_differ_by_at_most_one() {
        for (n, b) in [(0, 2), (1, 2), (7, 3), (1000, 2), (3000, 7)] {
            let blocks: Vec<_> = (0..b).map(|i| block(n, b, i)).collect();
            assert_eq!(blocks[0].0, 0);
            assert_eq!(blocks[b - 1].1, n);
            assert!(blocks.windows(2).all(|w| w[0].1 == w[1].0));
            let lens: Vec<_> = blocks.iter().map(|(s, e)| e - s).collect();
            assert!(
                lens.iter().max().unwrap() - lens.iter().min().unwrap() <= 1,
                "{lens:?}"
            );
        }
    }

    #[test]
    fn every_item_runs_once_and_the_first_error_comes_back() {
        for threads in [1, 3] {
            let team = Team::new(threads).unwrap();
            let mut items = vec![0u32; 5];
            team.each(&mut items, |i, x| {
                *x += i as u32 + 1;
                Ok::<(), String>(())
            })
            .unwrap();
            assert_eq!(items, vec![1, 2, 3, 4, 5]);
            let e = team.each(&mut items, |i, _| {
                if i == 3 {
                    Err(format!("item {i}"))
                } else {
                    Ok(())
                }
            });
            assert_eq!(e.unwrap_err(), "item 3");
        }
    }
}
