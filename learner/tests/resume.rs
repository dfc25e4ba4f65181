//! `ess train` stopped and resumed from its checkpoint continues bit-identically, in
//! both pipelines; overlapped runs are deterministic.
//!
//! Its own test binary, its tests one at a time ([`ONE_AT_A_TIME`]): libtorch's random
//! stream is process-global, and a run beside another in one process would draw from
//! it mid-run.

use ess_learner::logs;
use ess_learner::train::checkpoint::dir_for;
use ess_learner::train::{IterationLog, Progress, resume, run};
use ess_proto::config::{CheckedConfig, ConfigBuilder};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// Held by each test for its whole length.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

struct Quiet;
impl Progress for Quiet {
    fn iteration(&mut self, _: &IterationLog) {}
    fn message(&mut self, _: &str) {}
}

/// Sets `stop` once iteration `at` has been reported (a Ctrl-C during it).
struct StopAt {
    at: usize,
    stop: Arc<AtomicBool>,
}
impl Progress for StopAt {
    fn iteration(&mut self, it: &IterationLog) {
        if it.iteration == self.at {
            self.stop.store(true, Ordering::SeqCst);
        }
    }
    fn message(&mut self, _: &str) {}
}

fn small_config(extra: &[&str]) -> CheckedConfig {
    let mut b = ConfigBuilder::new();
    for kv in [
        "run.iterations=4",
        "run.eval_every=2",
        "run.checkpoint_every=0",
        "run.rollout_steps=150",
        "disc.steps=3",
        "disc.batch=32",
        "ppo.epochs=2",
        "ppo.minibatch=50",
        "run.eval_episodes=2",
        "run.eval_episodes_periodic=1",
        "run.reference_episodes=2",
        "demos.majority_episodes=4",
        "run.actors=2",
        // Threads: their mid-episode state is checkpointed, so resume is bit-identical.
        "run.transport=\"threads\"",
        "run.torch_threads=1",
    ]
    .iter()
    .chain(extra)
    {
        b.set(kv).expect(kv);
    }
    b.build().expect("config")
}

/// `metrics.csv` without its wall-clock columns (`*_s`).
fn metrics_without_times(dir: &Path) -> Vec<String> {
    let csv = std::fs::read_to_string(dir.join("metrics.csv")).expect("csv");
    let header = csv.lines().next().expect("header");
    let timed: Vec<usize> = header
        .split(',')
        .enumerate()
        .filter(|(_, c)| c.ends_with("_s"))
        .map(|(i, _)| i)
        .collect();
    assert!(!timed.is_empty(), "{header}");
    csv.lines()
        .map(|l| {
            l.split(',')
                .enumerate()
                .filter(|(i, _)| !timed.contains(i))
                .map(|(_, f)| f)
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect()
}

fn checkpoint_bytes(dir: &Path, it: usize) -> Vec<(String, Vec<u8>)> {
    let d = dir_for(&dir.join("checkpoints"), it);
    ["policy", "prior", "disc", "optim"]
        .iter()
        .map(|n| {
            let f = format!("{n}.safetensors");
            let bytes = std::fs::read(d.join(&f)).expect(&f);
            (f, bytes)
        })
        .collect()
}

/// Runs `cfg` whole, and stopped after iteration 2 then resumed: both end with the
/// same metrics, checkpoint bytes, NMI and p(c).
fn assert_resume_is_bit_identical(cfg: &CheckedConfig) {
    let whole = tempfile::tempdir().expect("tmp");
    let a = run(
        cfg,
        whole.path(),
        logs::open,
        &mut Quiet,
        &AtomicBool::new(false),
    )
    .expect("train");
    assert!(!a.summary.interrupted);

    let parts = tempfile::tempdir().expect("tmp");
    let stop = Arc::new(AtomicBool::new(false));
    let mut p = StopAt {
        at: 2,
        stop: stop.clone(),
    };
    let b1 = run(cfg, parts.path(), logs::open, &mut p, &stop).expect("first part");
    assert!(b1.summary.interrupted);
    assert_eq!(b1.summary.iterations, 2);
    let b2 = resume(
        parts.path(),
        logs::open,
        &mut Quiet,
        &AtomicBool::new(false),
    )
    .expect("resume");
    assert!(!b2.summary.interrupted);
    assert_eq!(b2.summary.iterations, 4);
    assert_eq!(b2.summary.env_steps, a.summary.env_steps);

    assert_eq!(
        metrics_without_times(whole.path()),
        metrics_without_times(parts.path())
    );
    for ((name, x), (_, y)) in checkpoint_bytes(whole.path(), 4)
        .iter()
        .zip(&checkpoint_bytes(parts.path(), 4))
    {
        assert!(x == y, "{name} differs after resuming");
    }
    assert_eq!(a.summary.nmi.to_bits(), b2.summary.nmi.to_bits());
    assert_eq!(a.summary.prior, b2.summary.prior);
}

#[test]
fn a_run_stopped_and_resumed_ends_bit_identical_to_an_uninterrupted_one() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    // The contrastive term draws libtorch noise, so that stream is covered too.
    assert_resume_is_bit_identical(&small_config(&["method.w_contrastive=0.1"]));
}

#[test]
fn an_overlapped_run_stopped_and_resumed_ends_bit_identical_to_an_uninterrupted_one() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    // The stop lands between collecting iteration 3's rollout and using it: the
    // checkpoint must bring back the actors from before it and its weights.
    assert_resume_is_bit_identical(&small_config(&[
        "method.w_contrastive=0.1",
        "run.pipeline=\"overlap\"",
    ]));
}

#[test]
fn overlapped_runs_repeat_exactly_and_differ_from_synchronous_ones() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let overlap = small_config(&["run.pipeline=\"overlap\""]);
    let dirs: Vec<_> = (0..2).map(|_| tempfile::tempdir().expect("tmp")).collect();
    for d in &dirs {
        run(
            &overlap,
            d.path(),
            logs::open,
            &mut Quiet,
            &AtomicBool::new(false),
        )
        .expect("train");
    }
    let (a, b) = (
        metrics_without_times(dirs[0].path()),
        metrics_without_times(dirs[1].path()),
    );
    assert_eq!(a, b, "two overlapped runs of one seed");
    let sync = tempfile::tempdir().expect("tmp");
    run(
        &small_config(&[]),
        sync.path(),
        logs::open,
        &mut Quiet,
        &AtomicBool::new(false),
    )
    .expect("train");
    let s = metrics_without_times(sync.path());
    // Iteration 1 is the same (its rollout is collected first in both); from
    // iteration 2 on the overlapped run learns from rollouts one version older.
    assert_eq!(a[1], s[1], "iteration 1");
    assert_ne!(
        a[2..],
        s[2..],
        "the overlapped run used the synchronous rollouts"
    );
}

#[test]
fn a_resumed_run_that_had_finished_only_evaluates_again() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let cfg = small_config(&["run.iterations=1"]);
    let dir = tempfile::tempdir().expect("tmp");
    let a = run(
        &cfg,
        dir.path(),
        logs::open,
        &mut Quiet,
        &AtomicBool::new(false),
    )
    .expect("train");
    let b = resume(dir.path(), logs::open, &mut Quiet, &AtomicBool::new(false)).expect("resume");
    assert_eq!(b.summary.iterations, 1);
    assert_eq!(b.summary.env_steps, a.summary.env_steps);
    assert_eq!(a.summary.nmi.to_bits(), b.summary.nmi.to_bits());
    let rows = std::fs::read_to_string(dir.path().join("metrics.csv")).expect("csv");
    assert_eq!(rows.lines().count(), 2, "{rows}");
}
