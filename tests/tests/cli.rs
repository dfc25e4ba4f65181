//! The `ess` command as a user runs it: bad input is rejected with one clear line and
//! exit code 2; every preset trains end to end and writes its outputs; SIGTERM stops a
//! run cleanly and `--resume` finishes it.

use ess_tests::{SMOKE, ess, ess_bin};
use std::io::BufRead;
use std::process::{Command, Stdio};

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn assert_input_error(args: &[&str], must_name: &str) {
    let o = ess(args);
    let err = stderr(&o);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{args:?} should exit 2; stderr: {err}"
    );
    let line = err
        .lines()
        .find(|l| l.starts_with("error"))
        .unwrap_or_else(|| panic!("no error line for {args:?}: {err}"));
    assert!(
        line.contains(must_name),
        "{args:?}: `{line}` should name `{must_name}`"
    );
}

#[test]
fn unknown_preset_is_rejected_naming_it() {
    assert_input_error(&["train", "--preset", "gial", "--print-config"], "gial");
}

#[test]
fn unknown_config_key_is_rejected_naming_it() {
    assert_input_error(
        &["train", "--set", "ppo.lrr=1", "--print-config"],
        "ppo.lrr",
    );
}

#[test]
fn wrong_type_is_rejected_naming_the_key() {
    assert_input_error(
        &["train", "--set", "run.iterations=lots", "--print-config"],
        "run.iterations",
    );
}

#[test]
fn out_of_range_values_are_rejected_naming_the_key() {
    for (set, key) in [
        ("demos.label_ratio=0", "demos.label_ratio"),
        ("demos.label_ratio=1.5", "demos.label_ratio"),
        ("demos.imbalance_ratio=0.5", "demos.imbalance_ratio"),
        ("env.n_modes=1", "env.n_modes"),
    ] {
        assert_input_error(&["train", "--set", set, "--print-config"], key);
    }
}

#[test]
fn unknown_env_is_rejected_naming_it() {
    assert_input_error(&["train", "--env", "mars", "--print-config"], "mars");
}

#[test]
fn config_file_with_unknown_key_is_rejected_naming_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("my.toml");
    std::fs::write(&f, "[run]\nseeds = 3\n").unwrap();
    let o = ess(&["train", "--config", f.to_str().unwrap(), "--print-config"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("run.seeds") && err.contains("my.toml"),
        "{err}"
    );
}

#[test]
fn corrupt_demo_file_is_rejected_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("demos.safetensors");
    std::fs::write(&f, b"not a safetensors file at all").unwrap();
    let o = ess(&["demos", "inspect", f.to_str().unwrap()]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("demos.safetensors"), "{err}");
}

#[test]
fn demos_generate_writes_a_file_that_inspect_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("d.safetensors");
    let o = ess(&[
        "demos",
        "generate",
        "--out",
        f.to_str().unwrap(),
        "--set",
        "demos.majority_episodes=10",
        "--set",
        "demos.imbalance_ratio=5",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = ess(&["demos", "inspect", f.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let meta: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        meta["unlabeled_episodes_per_mode"],
        serde_json::json!([10, 10, 2, 2])
    );
}

#[test]
fn every_preset_trains_a_few_iterations_and_writes_its_outputs() {
    let presets = [
        "gail",
        "infogail",
        "acgail",
        "elastic-infogail",
        "ess-infogail-no-gs",
        "ess-infogail-no-rim",
        "ess-infogail",
    ];
    let root = tempfile::tempdir().unwrap();
    let mut outs = Vec::new();
    for p in presets {
        let out = root.path().join(p);
        outs.push(out.to_str().unwrap().to_string());
        let mut args = vec!["train", "--preset", p, "--out", out.to_str().unwrap()];
        args.extend_from_slice(SMOKE);
        let o = ess(&args);
        assert!(o.status.success(), "{p}: {}", stderr(&o));
        for f in [
            "config.toml",
            "metrics.csv",
            "summary.json",
            "trajectories.png",
            "curves.png",
            "checkpoints/iter-000002/policy.safetensors",
        ] {
            assert!(out.join(f).exists(), "{p}: missing {f}");
        }
        let s: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                .unwrap();
        for key in [
            "nmi",
            "ent",
            "normalized_reward",
            "env_steps",
            "wall_seconds",
        ] {
            assert!(s[key].is_number(), "{p}: summary.json lacks {key}: {s}");
        }
        let nmi = s["nmi"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&nmi), "{p}: nmi {nmi}");
        assert_eq!(s["env_steps"].as_u64(), Some(800), "{p}");
        assert_eq!(s["method"].as_str(), Some(p));
        // metrics.csv: header + one row per iteration (the last with the final
        // evaluation).
        let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
        assert_eq!(csv.lines().count(), 1 + 2, "{p}: {csv}");
    }
    // `ess report` reads them all back: a row per run, a mean row per method.
    let mut args = vec!["report"];
    args.extend(outs.iter().map(String::as_str));
    let o = ess(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let table = String::from_utf8_lossy(&o.stdout);
    for p in presets {
        assert!(
            table.contains(&format!("| traj2d | {p} | 1 | ")),
            "{p}: {table}"
        );
    }
    // A directory without a summary is an input error naming the file.
    let o = ess(&["report", root.path().to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("summary.json"), "{}", stderr(&o));
}

#[test]
fn actors_default_to_one_process_per_core_and_0_is_one_thread() {
    let out = |args: &[&str]| String::from_utf8_lossy(&ess(args).stdout).into_owned();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let default = out(&["train", "--print-config"]);
    assert!(
        default.contains(&format!("actors = {cores}\n"))
            && default.contains("transport = \"processes\""),
        "{default}"
    );
    let zero = out(&["train", "--actors", "0", "--print-config"]);
    assert!(
        zero.contains("actors = 1\n") && zero.contains("transport = \"threads\""),
        "{zero}"
    );
    let three = out(&["train", "--actors", "3", "--print-config"]);
    assert!(
        three.contains("actors = 3\n") && three.contains("transport = \"processes\""),
        "{three}"
    );
}

#[test]
fn env_defaults_apply_under_the_preset_and_set_overrides_them() {
    let out = |args: &[&str]| String::from_utf8_lossy(&ess(args).stdout).into_owned();
    let reacher = out(&["train", "--env", "reacher", "--print-config"]);
    assert!(reacher.contains("n_modes = 6"), "{reacher}");
    assert!(reacher.contains("label_ratio = 0.005"), "{reacher}");
    // Reacher's information-reward weights reach Ess-InfoGAIL (its preset leaves them to
    // the defaults) but not GAIL, whose preset switches the terms off.
    assert!(reacher.contains("reward_qc = 1.0"), "{reacher}");
    let gail = out(&[
        "train",
        "--env",
        "reacher",
        "--preset",
        "gail",
        "--print-config",
    ]);
    assert!(gail.contains("reward_qc = 0.0"), "{gail}");
    // Reacher's [per_method.ess-infogail] table reaches that method only.
    assert!(reacher.contains("disc_code_reweight = true"), "{reacher}");
    assert!(
        reacher.contains("info_reward_warmup_iters = 120"),
        "{reacher}"
    );
    assert!(gail.contains("disc_code_reweight = false"), "{gail}");
    let humanoid = out(&["train", "--env", "humanoid", "--print-config"]);
    assert!(humanoid.contains("n_modes = 3") && humanoid.contains("label_ratio = 0.02"));
    let set = out(&[
        "train",
        "--env",
        "reacher",
        "--set",
        "env.n_modes=4",
        "--print-config",
    ]);
    assert!(set.contains("n_modes = 4"), "{set}");
    let traj = out(&["train", "--print-config"]);
    assert!(traj.contains("n_modes = 4") && traj.contains("label_ratio = 0.01"));
}

#[test]
fn every_mujoco_env_trains_a_few_iterations_from_its_shipped_experts() {
    for env in ["reacher", "pusher", "walker2d", "humanoid"] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("run");
        let mut args = vec!["train", "--env", env, "--out", out.to_str().unwrap()];
        args.extend_from_slice(SMOKE);
        args.extend_from_slice(&[
            "--set",
            "demos.majority_episodes=2",
            "--set",
            "run.reference_episodes=2",
        ]);
        let o = ess(&args);
        assert!(o.status.success(), "{env}: {}", stderr(&o));
        let s: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(s["env"], env);
        assert!(s["nmi"].as_f64().unwrap().is_finite(), "{env}: {s}");
    }
}

#[test]
fn sigterm_stops_training_cleanly_and_resume_finishes_the_run() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let mut child = Command::new(ess_bin())
        .args(["train", "--out", out.to_str().unwrap()])
        .args(SMOKE)
        .args([
            "--set",
            "run.iterations=40",
            "--set",
            "run.eval_every=0",
            "--set",
            "run.reference_episodes=2",
        ])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawning ess");
    // The loop has started once `ess: training` is printed; then SIGTERM.
    let mut lines = std::io::BufReader::new(child.stderr.take().unwrap()).lines();
    let mut seen = Vec::new();
    for l in lines.by_ref() {
        let l = l.unwrap();
        let started = l == "ess: training";
        seen.push(l);
        if started {
            break;
        }
    }
    assert_eq!(
        seen.last().map(String::as_str),
        Some("ess: training"),
        "{seen:?}"
    );
    let st = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(0), "{rest:?}");

    let summary = |dir: &std::path::Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
    };
    let s = summary(&out);
    assert_eq!(s["interrupted"], serde_json::json!(true), "{s}");
    let done = s["iterations"].as_u64().unwrap();
    assert!(done < 40, "{s}");
    assert!(
        out.join(format!("checkpoints/iter-{done:06}/state.json"))
            .exists()
    );

    let o = ess(&["train", "--resume", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = summary(&out);
    assert_eq!(s["interrupted"], serde_json::json!(false), "{s}");
    assert_eq!(s["iterations"].as_u64(), Some(40), "{s}");
    assert_eq!(s["env_steps"].as_u64(), Some(40 * 400), "{s}");
    let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
    let its: Vec<u64> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(its, (1..=40).collect::<Vec<u64>>(), "{csv}");
    // The run log reads like an uninterrupted run's: every iteration once, then the
    // final evaluation (the interrupted run's own final evaluation is dropped).
    let log = ess_learner::runlog::read(&out.join("run.mcap")).unwrap();
    assert_eq!(log.truncated, None);
    let mut logged = Vec::new();
    let mut finals = 0;
    for r in log.messages() {
        match r {
            ess_learner::runlog::Record::Metrics(m) => logged.push(u64::from(m.iteration)),
            ess_learner::runlog::Record::EvalEpisode(e) => finals += usize::from(e.final_eval),
            _ => {}
        }
    }
    let mut want: Vec<u64> = (1..=40).collect();
    want.push(40);
    assert_eq!(logged, want);
    assert_eq!(
        finals,
        4 * 2,
        "one final evaluation of 4 codes x 2 episodes"
    );
}

#[test]
fn resume_of_a_directory_without_a_run_is_rejected_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().join("nothing-here");
    assert_input_error(&["train", "--resume", d.to_str().unwrap()], "nothing-here");
}

#[test]
fn resume_refuses_a_new_configuration() {
    assert_input_error(
        &["train", "--resume", "runs/x", "--set", "run.iterations=3"],
        "--set",
    );
}

#[test]
fn disc_obs_prefix_trains_on_a_prefix_and_a_too_long_one_is_rejected_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad");
    let o = ess(&[
        "train",
        "--actors",
        "0",
        "--set",
        "disc.obs_prefix=1000",
        "--out",
        bad.to_str().unwrap(),
    ]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("disc.obs_prefix = 1000") && err.contains("traj2d"),
        "{err}"
    );
    assert!(!bad.exists(), "nothing is written for a rejected config");

    let out = dir.path().join("run");
    let mut args = vec![
        "train",
        "--actors",
        "0",
        "--set",
        "disc.obs_prefix=2",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(SMOKE);
    let o = ess(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let cfg = std::fs::read_to_string(out.join("config.toml")).unwrap();
    assert!(cfg.contains("obs_prefix = 2"), "{cfg}");
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert!(s["nmi"].as_f64().unwrap().is_finite(), "{s}");
}

#[test]
fn output_into_a_closed_pipe_ends_quietly_without_a_panic() {
    use nix::sys::signal::Signal;
    use std::os::unix::process::ExitStatusExt;
    // A pipe whose reader is gone before `ess` writes, as `| head` is after its lines.
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = Command::new(ess_bin())
        .arg("presets")
        .stdout(writer)
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(
        out.status.signal(),
        Some(Signal::SIGPIPE as i32),
        "{:?}: {err}",
        out.status
    );
    assert!(!err.contains("panicked"), "{err}");
}
