//! Threads over the batch: a step's rows are cut into one contiguous block per thread,
//! and each thread runs the whole forward (or backward) pass of its block on its own
//! buffers, so a step has one or two meeting points instead of one per layer. Block 0
//! runs on the calling thread, the others on the team's threads.
//!
//! The team's threads are kept between steps and **spin** for a while ([`SPIN`]) after
//! each piece of work before they sleep: a D/Q step's serial part (its loss terms over
//! the whole batch) lasts 50-100 us, longer than a general pool's idle workers search
//! before sleeping, and waking a sleeping thread cost more than the work it then did
//! (rayon-core's pool, measured first: bench/learner.md). Posting work allocates
//! nothing.

use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicU64, AtomicUsize, Ordering::SeqCst};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How long an idle thread spins before it sleeps.
pub const SPIN: Duration = Duration::from_micros(300);

/// The type-erased piece of work: called with the worker's index.
type Work<'a> = &'a (dyn Fn(usize) + Sync);

struct Shared {
    /// Bumped once per piece of work.
    epoch: AtomicU64,
    /// Points at a `Work` on the poster's stack, valid until `done` reaches the
    /// worker count.
    work: AtomicPtr<()>,
    /// Workers finished with the current epoch.
    done: AtomicUsize,
    /// A worker panicked in the current epoch.
    panicked: AtomicBool,
    stop: AtomicBool,
    sleepers: AtomicUsize,
    lock: Mutex<()>,
    wake: Condvar,
}

/// The learner's worker threads.
pub struct Team {
    threads: usize,
    shared: Arc<Shared>,
    handles: Vec<JoinHandle<()>>,
}

/// The team's threads could not be started.
#[derive(Debug, thiserror::Error)]
#[error("starting learner thread {index}: {source}")]
pub struct TeamError {
    index: usize,
    source: std::io::Error,
}

impl Team {
    /// A team of `threads` (at least 1: the calling thread alone).
    pub fn new(threads: usize) -> Result<Self, TeamError> {
        let threads = threads.max(1);
        let shared = Arc::new(Shared {
            epoch: AtomicU64::new(0),
            work: AtomicPtr::new(std::ptr::null_mut()),
            done: AtomicUsize::new(0),
            panicked: AtomicBool::new(false),
            stop: AtomicBool::new(false),
            sleepers: AtomicUsize::new(0),
            lock: Mutex::new(()),
            wake: Condvar::new(),
        });
        let mut team = Self {
            threads,
            shared,
            handles: Vec::new(),
        };
        for index in 1..threads {
            let s = team.shared.clone();
            let h = std::thread::Builder::new()
                .name(format!("ess-learner-{index}"))
                .spawn(move || worker(&s, index))
                .map_err(|source| TeamError { index, source })?;
            team.handles.push(h);
        }
        Ok(team)
    }

    /// Threads, the calling one included.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Runs `f(i, &mut items[i])` for every item (item `i` on thread `i % threads`,
    /// thread 0 being the caller) and returns when all are done: the first error any
    /// returned, if any. A panic in any of them is raised here once all are done.
    pub fn each<T: Send, E: Send>(
        &self,
        items: &mut [T],
        f: impl Fn(usize, &mut T) -> Result<(), E> + Sync,
    ) -> Result<(), E> {
        let (n, threads) = (items.len(), self.threads);
        let failed: Mutex<Option<E>> = Mutex::new(None);
        let base = SendPtr(items.as_mut_ptr());
        let run = |t: usize| {
            for i in (t..n).step_by(threads) {
                // SAFETY: thread `t` takes exactly the items `i % threads == t`, so no
                // two threads touch one item; `items` outlives this call (see below).
                let it = unsafe { &mut *base.at(i) };
                if let Err(e) = f(i, it)
                    && let Ok(mut slot) = failed.lock()
                {
                    slot.get_or_insert(e);
                }
            }
        };
        if threads == 1 || n <= 1 {
            run(0);
        } else {
            let work: Work = &run;
            let s = &*self.shared;
            s.done.store(0, SeqCst);
            s.panicked.store(false, SeqCst);
            s.work.store(&work as *const Work as *mut (), SeqCst);
            s.epoch.fetch_add(1, SeqCst);
            if s.sleepers.load(SeqCst) > 0 {
                let _g = s.lock.lock();
                s.wake.notify_all();
            }
            let mine = catch_unwind(AssertUnwindSafe(|| run(0)));
            // The workers read `work` and `items` until they have all counted
            // themselves done: wait for that before anything here goes out of scope,
            // a panic of this thread's share included.
            while s.done.load(SeqCst) < threads - 1 {
                std::hint::spin_loop();
            }
            if let Err(p) = mine {
                resume_unwind(p);
            }
            if s.panicked.load(SeqCst) {
                panic!("a learner thread panicked");
            }
        }
        match failed.into_inner() {
            Ok(Some(e)) => Err(e),
            _ => Ok(()),
        }
    }
}

impl Drop for Team {
    fn drop(&mut self) {
        self.shared.stop.store(true, SeqCst);
        {
            let _g = self.shared.lock.lock();
            self.shared.wake.notify_all();
        }
        for h in self.handles.drain(..) {
            let _ = h.join();
        }
    }
}

/// A raw pointer to the items, shared by the threads (each takes its own items).
struct SendPtr<T>(*mut T);

impl<T> Clone for SendPtr<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for SendPtr<T> {}
// SAFETY: the pointer is only dereferenced at disjoint indices, one thread each.
unsafe impl<T: Send> Sync for SendPtr<T> {}
unsafe impl<T: Send> Send for SendPtr<T> {}

impl<T> SendPtr<T> {
    fn at(self, i: usize) -> *mut T {
        // SAFETY: callers pass indices below the slice's length.
        unsafe { self.0.add(i) }
    }
}

/// A team thread: wait for a new epoch (spinning, then sleeping), run its share, count
/// itself done.
fn worker(s: &Shared, index: usize) {
    let mut seen = 0u64;
    loop {
        let started = Instant::now();
        let mut spins = 0u32;
        loop {
            if s.stop.load(SeqCst) {
                return;
            }
            let e = s.epoch.load(SeqCst);
            if e != seen {
                seen = e;
                break;
            }
            spins = spins.wrapping_add(1);
            if !spins.is_multiple_of(64) || started.elapsed() < SPIN {
                std::hint::spin_loop();
                continue;
            }
            s.sleepers.fetch_add(1, SeqCst);
            if let Ok(mut g) = s.lock.lock() {
                while s.epoch.load(SeqCst) == seen && !s.stop.load(SeqCst) {
                    g = match s.wake.wait(g) {
                        Ok(g) => g,
                        Err(p) => p.into_inner(),
                    };
                }
            }
            s.sleepers.fetch_sub(1, SeqCst);
        }
        let ptr = s.work.load(SeqCst) as *const Work;
        // SAFETY: the poster stored a pointer to a live `Work` before bumping the
        // epoch and keeps it alive until this thread counts itself done.
        let work: Work = unsafe { *ptr };
        if catch_unwind(AssertUnwindSafe(|| work(index))).is_err() {
            s.panicked.store(true, SeqCst);
        }
        s.done.fetch_add(1, SeqCst);
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
        for threads in [1, 2, 3] {
            let team = Team::new(threads).unwrap();
            for round in 0..200u32 {
                let mut items = vec![0u32; 5];
                team.each(&mut items, |i, x| {
                    *x += i as u32 + round;
                    Ok::<(), String>(())
                })
                .unwrap();
                assert_eq!(items, (0..5).map(|i| i + round).collect::<Vec<_>>());
            }
            let mut items = vec![0u32; 5];
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

    #[test]
    fn a_team_that_slept_wakes_for_the_next_piece_of_work() {
        let team = Team::new(2).unwrap();
        let mut items = vec![0u8; 2];
        std::thread::sleep(SPIN * 4);
        team.each(&mut items, |_, x| {
            *x = 1;
            Ok::<(), ()>(())
        })
        .unwrap();
        assert_eq!(items, vec![1, 1]);
    }

    #[test]
    fn a_panic_on_a_team_thread_reaches_the_caller_and_the_team_goes_on() {
        let team = Team::new(2).unwrap();
        let mut items = vec![0u8; 2];
        let r = catch_unwind(AssertUnwindSafe(|| {
            team.each(&mut items, |i, _| {
                assert!(i != 1, "boom");
                Ok::<(), ()>(())
            })
        }));
        assert!(r.is_err());
        team.each(&mut items, |_, x| {
            *x = 2;
            Ok::<(), ()>(())
        })
        .unwrap();
        assert_eq!(items, vec![2, 2]);
    }
}
