//! Helpers for the cross-process tests in `tests/tests/`: they run the real `ess`
//! binary (built by `make test` before the tests) and check what it prints and writes.

use std::path::PathBuf;
use std::process::{Command, Output};

/// Path of the `ess` binary: `$ESS_BIN`, else the one beside this test executable's
/// profile directory (`target/<profile>/ess`).
pub fn ess_bin() -> PathBuf {
    if let Ok(p) = std::env::var("ESS_BIN") {
        return PathBuf::from(p);
    }
    let exe = std::env::current_exe().expect("test executable path");
    // target/<profile>/deps/<test-exe>
    let profile_dir = exe
        .parent()
        .and_then(|d| d.parent())
        .expect("target/<profile> directory");
    let bin = profile_dir.join("ess");
    assert!(
        bin.exists(),
        "{} not found: build it first (`cargo build -p ess-learner --bin ess`, as `make test` does) or set ESS_BIN",
        bin.display()
    );
    bin
}

/// Runs `ess` with `args`; returns its output.
pub fn ess(args: &[&str]) -> Output {
    Command::new(ess_bin())
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("running ess")
}

/// Settings that make a training run take seconds: for smoke tests only.
pub const SMOKE: &[&str] = &[
    "--set",
    "run.iterations=2",
    "--set",
    "run.rollout_steps=400",
    "--set",
    "disc.steps=3",
    "--set",
    "disc.batch=64",
    "--set",
    "ppo.epochs=2",
    "--set",
    "ppo.minibatch=200",
    "--set",
    "run.eval_episodes=2",
    "--set",
    "run.eval_every=1",
    "--set",
    "run.eval_episodes_periodic=1",
    "--set",
    "demos.majority_episodes=20",
    "--set",
    "run.torch_threads=1",
];
