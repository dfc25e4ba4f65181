//! The dependency rules the design relies on, checked on the resolved build graph
//! (`cargo tree` of each crate):
//!
//! - `ess-actor` never links libtorch (`tch`, `torch-sys`): an actor process carries the
//!   pure-Rust policy forward only;
//! - `ess-envs` never pulls in an async runtime (`tokio`): the envs are plain stepping
//!   code that actors, learner and tests call synchronously;
//! - `ess-proto` depends on no other crate of ours: it holds the contracts everyone
//!   else speaks.

use std::collections::BTreeSet;
use std::process::Command;

/// The names of every package `member` links (normal dependencies, itself included),
/// as `cargo tree -p member` resolves them for x86_64 Linux, the platform Ess builds
/// for: features as when that crate is built on its own.
fn links(member: &str) -> BTreeSet<String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args([
            "tree", "--locked", "-p", member, "-e", "normal", "--prefix", "none",
        ])
        .args(["--target", "x86_64-unknown-linux-gnu", "-f", "{p}"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo tree runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_whitespace().next().map(String::from))
        .collect()
}

const OURS: [&str; 5] = [
    "ess-proto",
    "ess-envs",
    "ess-actor",
    "ess-learner",
    "ess-tests",
];

#[test]
fn the_crates_depend_on_each_other_only_as_the_design_allows() {
    let actor = links("ess-actor");
    for torch in ["tch", "torch-sys"] {
        assert!(!actor.contains(torch), "ess-actor links {torch}");
    }
    assert!(
        actor.contains("ess-envs") && actor.contains("iceoryx2"),
        "{actor:?}"
    );
    let envs = links("ess-envs");
    assert!(!envs.contains("tokio"), "ess-envs pulls in tokio");
    assert!(!envs.contains("tch"), "ess-envs links tch");
    let proto = links("ess-proto");
    let ours: Vec<&str> = OURS
        .into_iter()
        .filter(|m| *m != "ess-proto" && proto.contains(*m))
        .collect();
    assert!(ours.is_empty(), "ess-proto depends on {ours:?}");
    // The rules bite: the learner does link what the actor and the envs must not.
    let learner = links("ess-learner");
    assert!(
        learner.contains("tch") && learner.contains("tokio"),
        "{learner:?}"
    );
}
