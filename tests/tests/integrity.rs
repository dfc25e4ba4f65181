//! Every file Ess writes and reads back carries checksums: a flipped byte inside a
//! demonstration file, an expert, any file of a checkpoint, an expert's training state
//! or a SAC replay buffer is refused with one error naming the file (and the tensor),
//! where before it loaded silently.

use ess_tests::{SMOKE, ess};
use std::path::{Path, PathBuf};

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Flips one bit of the last byte of `path` (always tensor data in a safetensors file).
fn flip_last_byte(path: &Path) {
    let mut b = std::fs::read(path).unwrap();
    let n = b.len();
    b[n - 1] ^= 0x04;
    std::fs::write(path, b).unwrap();
}

/// Turns one decimal digit of a JSON file into another: still valid JSON, other numbers.
fn change_a_digit(path: &Path) {
    let mut b = std::fs::read(path).unwrap();
    let at = b.iter().rposition(|c| c.is_ascii_digit()).unwrap();
    b[at] = if b[at] == b'7' { b'8' } else { b'7' };
    std::fs::write(path, b).unwrap();
}

/// Copies directory `from` to `to` (flat files and one level of subdirectories).
fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dst = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &dst);
        } else {
            std::fs::copy(e.path(), dst).unwrap();
        }
    }
}

fn assert_refused(o: &std::process::Output, file: &str, what: &str) {
    let err = stderr(o);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{what}: not an input error\n{err}"
    );
    let last = err
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .unwrap_or("");
    assert!(
        last.contains(file),
        "{what}: the error does not name {file}: {err}"
    );
    assert!(
        last.contains("checksum") && last.contains("corrupt"),
        "{what}: {err}"
    );
}

#[test]
fn a_flipped_byte_in_a_demonstration_file_is_refused_naming_file_and_tensor() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("d.safetensors");
    let fs = f.to_str().unwrap();
    let set = [
        "--set",
        "demos.majority_episodes=4",
        "--set",
        "demos.imbalance_ratio=2",
    ];
    let mut args = vec!["demos", "generate", "--out", fs];
    args.extend(set);
    let o = ess(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(ess(&["demos", "inspect", fs]).status.success());
    flip_last_byte(&f);
    let o = ess(&["demos", "inspect", fs]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert_refused(&o, "d.safetensors", "demos");
    assert!(stderr(&o).contains("tensor `"), "{}", stderr(&o));
}

#[test]
fn a_flipped_byte_in_any_checkpoint_file_stops_the_resume_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let mut args = vec!["train", "--actors", "0", "--out", run.to_str().unwrap()];
    args.extend_from_slice(SMOKE);
    args.extend_from_slice(&[
        "--set",
        "run.reference_episodes=2",
        "--set",
        "run.eval_every=0",
    ]);
    let o = ess(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let ckpt = |root: &Path| -> PathBuf { root.join("checkpoints").join("iter-000002") };
    assert!(ckpt(&run).join("state.json").is_file());
    // The untouched copy resumes (a finished run evaluates again).
    let clean = tmp.path().join("clean");
    copy_dir(&run, &clean);
    let o = ess(&["train", "--resume", clean.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    for file in [
        "policy.safetensors",
        "prior.safetensors",
        "disc.safetensors",
        "optim.safetensors",
        "state.json",
        "state.sha256",
    ] {
        let copy = tmp.path().join(format!("bad-{file}"));
        copy_dir(&run, &copy);
        let target = ckpt(&copy).join(file);
        if !file.ends_with(".safetensors") {
            change_a_digit(&target);
        } else {
            flip_last_byte(&target);
        }
        let o = ess(&["train", "--resume", copy.to_str().unwrap()]);
        // A changed checksum file is named as the one state.json fails to match.
        assert_refused(&o, file.replace("sha256", "json").as_str(), file);
    }
}

#[test]
fn a_flipped_byte_in_an_expert_its_state_or_its_replay_buffer_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("mode1.safetensors");
    let os = out.to_str().unwrap();
    let train = |steps: &str, extra: &[&str]| {
        let mut a = vec![
            "experts",
            "train",
            "--env",
            "reacher",
            "--set",
            "env.n_modes=2",
        ];
        a.extend_from_slice(&["--mode", "1", "--out", os, "--steps", steps]);
        a.extend_from_slice(&[
            "--set",
            "run.rollout_steps=100",
            "--set",
            "run.torch_threads=1",
        ]);
        a.extend_from_slice(&["--algo", "sac", "--set", "sac.hidden=[16, 16]"]);
        a.extend_from_slice(&["--set", "sac.batch=16", "--set", "sac.buffer=1000"]);
        a.extend_from_slice(&[
            "--set",
            "sac.learning_starts=50",
            "--set",
            "sac.log_every=100",
        ]);
        a.extend_from_slice(extra);
        ess(&a)
    };
    let o = train("300", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let with = |suffix: &str| PathBuf::from(format!("{os}{suffix}"));
    let saved: Vec<(PathBuf, Vec<u8>)> = ["", ".state.safetensors", ".replay.safetensors"]
        .iter()
        .map(|s| (with(s), std::fs::read(with(s)).unwrap()))
        .collect();
    for (path, bytes) in &saved {
        flip_last_byte(path);
        let name = path.file_name().unwrap().to_str().unwrap();
        let o = train("400", &["--resume"]);
        assert_refused(&o, name, name);
        std::fs::write(path, bytes).unwrap();
    }
    // Restored, it resumes.
    let o = train("400", &["--resume"]);
    assert!(o.status.success(), "{}", stderr(&o));
}
