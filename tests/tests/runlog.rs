//! The MCAP run log as a user meets it: `ess train` writes `run.mcap`, `ess replay`
//! lists and re-simulates its episodes; a SIGTERM finalises the file and a SIGKILL
//! leaves every complete iteration readable.

use ess_learner::runlog::{Record, read};
use ess_tests::{SMOKE, ess, ess_bin};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn train(out: &Path, extra: &[&str]) {
    let mut args = vec![
        "train",
        "--env",
        "traj2d",
        "--out",
        out.to_str().unwrap(),
        "--set",
        "run.log_chunks_every=1",
        "--set",
        "run.log_periodic_evals=true",
    ];
    args.extend_from_slice(SMOKE);
    args.extend_from_slice(extra);
    let o = ess(&args);
    assert!(o.status.success(), "ess train failed: {}", stderr(&o));
}

fn replay_json(args: &[&str]) -> serde_json::Value {
    let mut a = vec!["replay"];
    a.extend_from_slice(args);
    a.push("--json");
    let o = ess(&a);
    assert!(o.status.success(), "ess {a:?} failed: {}", stderr(&o));
    serde_json::from_slice(&o.stdout).expect("replay prints JSON")
}

/// Trains, then replays every final-evaluation episode of the run log.
fn train_and_replay_every_final_episode(extra: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    train(dir.path(), extra);
    let file = dir.path().join("run.mcap");
    let log = read(&file).unwrap();
    assert_eq!(log.truncated, None, "a finished run's log is complete");
    let msgs: Vec<&Record> = log.messages().collect();
    assert!(matches!(msgs[0], Record::Config(c) if c.env == "traj2d"));
    let iterations: Vec<u32> = msgs
        .iter()
        .filter_map(|r| match r {
            Record::Metrics(m) => Some(m.iteration),
            _ => None,
        })
        .collect();
    // Two iterations, then the final evaluation repeating the last one.
    assert_eq!(iterations, [1, 2, 2]);
    assert!(
        msgs.iter()
            .any(|r| matches!(r, Record::TrainingChunk(c) if c.len > 0))
    );

    let file = file.to_str().unwrap();
    let list = replay_json(&[file]);
    let finals: Vec<u64> = list
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["final_eval"] == true)
        .map(|e| e["episode"].as_u64().unwrap())
        .collect();
    // 4 codes x run.eval_episodes = 2.
    assert_eq!(finals.len(), 8, "{list}");
    for ep in finals {
        let ep = ep.to_string();
        let r = replay_json(&[file, "--episode", &ep]);
        assert_eq!(r["within_tol"], true, "{r}");
        assert!(r["max_state_deviation"].as_f64().unwrap() < 1e-6, "{r}");
        assert!(r["steps"].as_u64().unwrap() > 1, "{r}");
    }
}

#[test]
fn episodes_of_a_trained_run_replay_within_tolerance() {
    train_and_replay_every_final_episode(&[]);
}

#[test]
fn episodes_evaluated_in_actor_processes_carry_their_states_and_replay() {
    train_and_replay_every_final_episode(&["--actors", "2"]);
}

#[test]
fn replay_rejects_bad_input_naming_the_file_or_episode() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.mcap");
    let text = dir.path().join("config.toml");
    std::fs::write(&text, "[run]\nseed = 1\n").unwrap();
    for (args, must_name) in [
        (vec![missing.to_str().unwrap()], "missing.mcap"),
        (vec![text.to_str().unwrap()], "not an MCAP file"),
    ] {
        let mut a = vec!["replay"];
        a.extend(args);
        let o = ess(&a);
        assert_eq!(o.status.code(), Some(2), "{a:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(must_name), "{a:?}: {}", stderr(&o));
    }
    train(dir.path(), &[]);
    let file = dir.path().join("run.mcap");
    let o = ess(&["replay", file.to_str().unwrap(), "--episode", "999"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("episode 999"), "{}", stderr(&o));
}

/// Starts a long `ess train` and waits until its log holds `iterations` metrics; the
/// caller stops and waits for the returned child.
#[allow(clippy::zombie_processes)]
fn start_long_run(out: &Path, iterations: u32) -> std::process::Child {
    let mut child = Command::new(ess_bin())
        .args([
            "train",
            "--env",
            "traj2d",
            "--out",
            out.to_str().unwrap(),
            "--set",
            "run.iterations=100000",
            "--set",
            "run.rollout_steps=200",
            "--set",
            "disc.steps=1",
            "--set",
            "ppo.epochs=1",
            "--set",
            "run.eval_every=0",
            "--set",
            "run.eval_episodes=1",
            "--set",
            "run.reference_episodes=2",
            "--set",
            "demos.majority_episodes=4",
            "--set",
            "run.torch_threads=1",
        ])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawning ess train");
    let file = out.join("run.mcap");
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let n = read(&file)
            .map(|l| {
                l.messages()
                    .filter(|r| matches!(r, Record::Metrics(_)))
                    .count()
            })
            .unwrap_or(0);
        if n >= iterations as usize {
            return child;
        }
        if Instant::now() >= deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("no {iterations} iterations logged within 120 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_killed_run_leaves_every_complete_iteration_readable() {
    let dir = tempfile::tempdir().unwrap();
    let mut child = start_long_run(dir.path(), 3);
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let log = read(&dir.path().join("run.mcap")).unwrap();
    assert!(log.truncated.is_some(), "a killed run has no summary");
    let iterations: Vec<u32> = log
        .messages()
        .filter_map(|r| match r {
            Record::Metrics(m) => Some(m.iteration),
            _ => None,
        })
        .collect();
    assert!(iterations.len() >= 3, "{iterations:?}");
    assert_eq!(
        iterations,
        (1..=iterations.len() as u32).collect::<Vec<_>>()
    );
    // `ess replay` lists a truncated log too.
    let o = ess(&["replay", dir.path().join("run.mcap").to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("truncated"), "{}", stderr(&o));
}

#[test]
fn sigterm_finishes_the_log_with_the_final_evaluation() {
    let dir = tempfile::tempdir().unwrap();
    let mut child = start_long_run(dir.path(), 2);
    let st = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    let status = child.wait().unwrap();
    assert!(status.success(), "{status:?}");
    let log = read(&dir.path().join("run.mcap")).unwrap();
    assert_eq!(log.truncated, None, "the log is finalised");
    assert!(
        log.messages()
            .any(|r| matches!(r, Record::EvalEpisode(e) if e.final_eval))
    );
}
