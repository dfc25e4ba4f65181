//! Actor processes (`ess-actor`) feeding the learner over iceoryx2 shared memory: chunks
//! arrive intact and equal to the in-process path's, one actor process trains to the same
//! numbers as one actor thread, `kill -9` of an actor or of the learner is survived, and no
//! process is left behind.

use ess_actor::shm::nodes_named;
use ess_actor::{LatentSpec, LocalEval, PolicyWeights, RolloutSource, ThreadedActors, Worker};
use ess_learner::actors::{ShmActors, ShmActorsConfig, new_run_id};
use ess_learner::eval::{Reference, build_reference, evaluate};
use ess_proto::config::LatentPrior;
use ess_proto::weights::MlpLayout;
use ess_proto::{Chunk, Mlp};
use ess_tests::{SMOKE, actor_bin, children_of, ess, ess_bin, is_running, wait_gone};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

const ENV: &str = "traj2d";
const OBS: usize = 10;
const ACT: usize = 1;
const K: usize = 4;

fn latent() -> LatentSpec {
    latent_k(K)
}

fn latent_k(k: usize) -> LatentSpec {
    LatentSpec {
        prior: LatentPrior::Gumbel,
        n_codes: k,
        tau: 0.1,
        use_eps: true,
    }
}

/// Deterministic non-trivial weights of version `version`.
fn weights(version: u64) -> Arc<PolicyWeights> {
    weights_for(OBS, ACT, K, version, 0.0)
}

/// Deterministic non-trivial weights for an env's dims; `shift` changes the parameters
/// without changing the version.
fn weights_for(od: usize, ad: usize, k: usize, version: u64, shift: f32) -> Arc<PolicyWeights> {
    let layout = MlpLayout::new(od + 1 + k, &[8], ad).unwrap();
    let params = (0..layout.n_params())
        .map(|i| ((i as f32 * 0.37 + version as f32 + shift).sin()) * 0.5)
        .collect();
    let mut prior_logits: Vec<f32> = (0..k).map(|j| 0.1 * j as f32 - 0.2).collect();
    prior_logits[0] = 0.1 * version as f32;
    Arc::new(PolicyWeights {
        version,
        mean: Mlp::new(layout, params).unwrap(),
        log_std: vec![-0.5; ad],
        prior_logits,
        obs_mean: vec![0.05; od],
        obs_std: vec![1.5; od],
    })
}

/// Heartbeat timeout of the tests that compare numbers between runs: long enough that a
/// starved machine never restarts (and so reseeds) an actor that is only slow. Tests of
/// hang detection use short ones and compare nothing a restart changes.
const STEADY: Duration = Duration::from_secs(120);
/// The same for `ess train`.
const STEADY_SET: [&str; 2] = ["--set", "run.actor_timeout_s=120"];

fn shm_actors(seeds: &[u64], max_steps: usize) -> ShmActors {
    shm_actors_on(ENV, K, seeds, max_steps, STEADY)
}

fn shm_actors_on(
    env: &str,
    k: usize,
    seeds: &[u64],
    max_steps: usize,
    heartbeat_timeout: Duration,
) -> ShmActors {
    ShmActors::new(ShmActorsConfig {
        run_id: new_run_id(),
        binary: actor_bin(),
        env: env.into(),
        n_modes: k,
        latent: latent_k(k),
        seeds: seeds.to_vec(),
        max_steps,
        heartbeat_timeout,
        startup_timeout: Duration::from_secs(30),
        plain_env: false,
        task_mode: None,
    })
    .expect("starting actor processes")
}

/// A cheap reference (one expert episode per mode) for comparing evaluations.
fn reference(env: &str, k: usize) -> Reference {
    let mut e = ess_envs::make_env(env, k).unwrap();
    build_reference(e.as_mut(), 1, 7).unwrap()
}

/// Evaluates `w` in this process and through `procs`' actors: same confusion matrix,
/// returns and episodes (every field).
fn assert_same_evaluation(
    env: &str,
    k: usize,
    reference: &Reference,
    procs: &mut ShmActors,
    w: &PolicyWeights,
    episodes: usize,
) {
    let mut local_env = ess_envs::make_env(env, k).unwrap();
    let (a, ea) = evaluate(
        reference,
        &mut LocalEval(local_env.as_mut()),
        w,
        &latent_k(k),
        episodes,
        0xE7A1,
    )
    .unwrap();
    let runner = procs.evaluator().expect("actor processes run evaluations");
    let (b, eb) = evaluate(reference, runner, w, &latent_k(k), episodes, 0xE7A1).unwrap();
    assert_eq!(ea.len(), k * episodes);
    assert!(ea.iter().all(|e| !e.is_empty()));
    assert_eq!(ea, eb, "{env}: episodes differ");
    assert_eq!(a.confusion, b.confusion, "{env}: confusion");
    assert_eq!(a.assignment, b.assignment, "{env}: assignment");
    for (x, y) in [
        (a.nmi, b.nmi),
        (a.ent, b.ent),
        (a.normalized_reward, b.normalized_reward),
        (a.label_accuracy, b.label_accuracy),
    ] {
        assert_eq!(x.to_bits(), y.to_bits(), "{env}");
    }
    assert_eq!(a.normalized_reward_per_code, b.normalized_reward_per_code);
}

#[test]
fn evaluation_in_actor_processes_equals_the_in_process_one() {
    for (env, k, n_actors) in [(ENV, K, 2usize), ("reacher", 6, 3)] {
        let reference = reference(env, k);
        let spec = ess_envs::make_env(env, k).unwrap().spec().clone();
        let seeds: Vec<u64> = (0..n_actors as u64).map(|i| 21 + i).collect();
        let mut procs = shm_actors_on(env, k, &seeds, 200, STEADY);
        let pids = procs.pids();
        // A rollout, then an evaluation whose weights carry the same caller version with
        // other parameters (as in training: evaluated after the update), then the next
        // rollout: the actors must act with the right weights each time.
        procs
            .collect(weights_for(spec.obs_dim, spec.act_dim, k, 1, 0.0), 200)
            .unwrap();
        let w = weights_for(spec.obs_dim, spec.act_dim, k, 1, 0.5);
        assert_same_evaluation(env, k, &reference, &mut procs, &w, 2);
        let chunks = procs
            .collect(weights_for(spec.obs_dim, spec.act_dim, k, 2, 0.0), 200)
            .unwrap();
        assert!(chunks.iter().all(|c| c.policy_version == 2));
        drop(procs);
        assert_eq!(wait_gone(&pids, 5.0), Vec::<u32>::new(), "left behind");
    }
}

#[test]
fn a_dead_or_hung_actor_during_evaluation_is_replaced_and_its_job_run_again() {
    let reference = reference(ENV, K);
    let mut procs = shm_actors_on(ENV, K, &[31, 32], 100, Duration::from_secs(1));
    procs.collect(weights(1), 100).unwrap();
    let pids = procs.pids();
    let signal = |sig: &str, pid: u32| {
        let st = Command::new("kill")
            .args([sig, &pid.to_string()])
            .status()
            .unwrap();
        assert!(st.success());
    };
    signal("-KILL", pids[0]);
    signal("-STOP", pids[1]);
    assert_same_evaluation(ENV, K, &reference, &mut procs, &weights(2), 3);
    let fresh = procs.pids();
    assert!(
        fresh[0] != pids[0] && fresh[1] != pids[1],
        "{pids:?} -> {fresh:?}"
    );
    assert!(procs.collect(weights(3), 100).is_ok());
    drop(procs);
    let all: Vec<u32> = pids.iter().chain(&fresh).copied().collect();
    assert_eq!(wait_gone(&all, 5.0), Vec::<u32>::new(), "left behind");
}

#[test]
fn imitation_chunks_carry_the_shared_reward_and_a_fall_costs_it() {
    // Walker2d: 17 observations, 6 actions, 3 modes; random-ish weights fall often.
    let workers = vec![Worker::new(
        ess_envs::make_env("walker2d", 3).unwrap(),
        5,
        3,
    )];
    let mut threads = ThreadedActors::new(workers, latent_k(3));
    let c = threads.collect(weights_for(17, 6, 3, 1, 0.0), 400).unwrap();
    let (mut falls, mut upright) = (0, 0);
    for (r, &fell) in c[0].env_reward.iter().zip(&c[0].terminated) {
        // 0.6 |vx| + 0.3 upright, 0.6 |vx| - 30 on the step that falls.
        if fell {
            falls += 1;
            assert!(*r < -25.0, "fall {r}");
        } else {
            upright += 1;
            assert!(*r >= 0.3 - 1e-5, "upright {r}");
        }
    }
    assert!(falls > 0 && upright > 0, "falls {falls}, upright {upright}");
}

#[test]
fn process_chunks_equal_thread_chunks_in_every_field() {
    let seeds = [11u64, 12];
    let mut procs = shm_actors(&seeds, 300);
    let pids = procs.pids();
    assert_eq!(pids.len(), 2);
    let workers = seeds
        .iter()
        .map(|&s| Worker::new(ess_envs::make_env(ENV, K).unwrap(), s, K))
        .collect();
    let mut threads = ThreadedActors::new(workers, latent());
    // Uneven split (301 = 151 + 150), episodes that carry over between rollouts, and
    // versions that do not go back.
    for version in 1..=3 {
        let w = weights(version);
        let a: Vec<Chunk> = procs.collect(w.clone(), 301).unwrap();
        let b: Vec<Chunk> = threads.collect(w, 301).unwrap();
        assert_eq!(a.len(), 2);
        assert_eq!(a[0].len(), 151);
        assert_eq!(a[1].len(), 150);
        for c in &a {
            assert_eq!(c.policy_version, version);
        }
        // Chunk's PartialEq compares every field; no NaN can occur here.
        assert_eq!(a, b, "rollout of version {version}");
    }
    // A version may repeat (the overlap pipeline's first two rollouts) but never go
    // back.
    let a = procs.collect(weights(3), 10).unwrap();
    let b = threads.collect(weights(3), 10).unwrap();
    assert_eq!(a, b, "the repeated version");
    assert!(procs.collect(weights(2), 10).is_err());
    // Fewer steps than actors: actor 1's share is empty and still answered.
    let a = procs.collect(weights(4), 1).unwrap();
    let b = threads.collect(weights(4), 1).unwrap();
    assert_eq!((a[0].len(), a[1].len()), (1, 0));
    assert_eq!(a, b);
    let run_id = procs.run_id().to_owned();
    assert_eq!(nodes_named(&run_id).unwrap().len(), 3, "learner + 2 actors");
    drop(procs);
    assert_eq!(
        wait_gone(&pids, 5.0),
        Vec::<u32>::new(),
        "actors still running"
    );
    assert_eq!(
        nodes_named(&run_id).unwrap(),
        vec![],
        "the run's iceoryx2 nodes are removed"
    );
}

fn summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json");
    serde_json::from_str(&text).expect("summary.json is JSON")
}

/// `metrics.csv` without its timing columns.
fn metrics_without_timings(dir: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(dir.join("metrics.csv")).expect("metrics.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let keep: Vec<usize> = (0..header.len())
        .filter(|&i| !header[i].ends_with("_s"))
        .collect();
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            keep.iter().map(|&i| f[i].to_string()).collect()
        })
        .collect()
}

#[test]
fn one_actor_process_trains_to_the_same_numbers_as_one_thread() {
    let tmp = tempfile::tempdir().unwrap();
    let (thr, prc) = (tmp.path().join("threads"), tmp.path().join("processes"));
    let run = |out: &Path, extra: &[&str]| {
        let mut args = vec!["train", "--seed", "3", "--out", out.to_str().unwrap()];
        args.extend_from_slice(SMOKE);
        args.extend_from_slice(&["--set", "run.reference_episodes=2"]);
        args.extend_from_slice(&STEADY_SET);
        args.extend_from_slice(extra);
        let o = ess(&args);
        assert!(
            o.status.success(),
            "{extra:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    };
    run(&thr, &["--actors", "0"]);
    run(&prc, &["--actors", "1"]);
    let (a, b) = (summary(&thr), summary(&prc));
    for key in ["nmi", "ent", "normalized_reward", "env_steps"] {
        assert_eq!(a[key], b[key], "summary.json `{key}`");
    }
    assert_eq!(metrics_without_timings(&thr), metrics_without_timings(&prc));
}

#[test]
fn two_runs_at_once_never_see_each_others_actors() {
    let tmp = tempfile::tempdir().unwrap();
    let outs = [tmp.path().join("a"), tmp.path().join("b")];
    let children: Vec<_> = outs
        .iter()
        .map(|o| spawn_training_with(o, "2", "4", &STEADY_SET))
        .collect();
    for (c, o) in children.into_iter().zip(&outs) {
        let r = c.wait_with_output().unwrap();
        assert!(
            r.status.success(),
            "{}: {}",
            o.display(),
            String::from_utf8_lossy(&r.stderr)
        );
    }
    // Same seed, same actors: identical runs, whatever the other run published.
    assert_eq!(
        metrics_without_timings(&outs[0]),
        metrics_without_timings(&outs[1])
    );
    assert_eq!(summary(&outs[0])["env_steps"], 4 * 400);
}

/// Starts `ess train` with actor processes in the background.
fn spawn_training(out: &Path, actors: &str, iterations: &str) -> std::process::Child {
    spawn_training_with(out, actors, iterations, &[])
}

fn spawn_training_with(
    out: &Path,
    actors: &str,
    iterations: &str,
    extra: &[&str],
) -> std::process::Child {
    Command::new(ess_bin())
        .args(["train", "--out", out.to_str().unwrap(), "--actors", actors])
        .args(SMOKE)
        .args([
            "--set",
            &format!("run.iterations={iterations}"),
            "--set",
            "run.reference_episodes=2",
            "--set",
            "run.eval_every=0",
        ])
        .args(extra)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawning ess")
}

/// Waits until `metrics.csv` in `out` has a row for iteration `it`.
fn wait_for_iteration(out: &Path, it: usize, child: &mut std::process::Child) {
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let rows = std::fs::read_to_string(out.join("metrics.csv"))
            .map(|t| t.lines().count().saturating_sub(1))
            .unwrap_or(0);
        if rows >= it {
            return;
        }
        if let Ok(Some(st)) = child.try_wait() {
            panic!("ess exited ({st}) before iteration {it}");
        }
        assert!(Instant::now() < deadline, "no iteration {it} in time");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_killed_actor_is_restarted_and_the_run_completes() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let mut child = spawn_training(&out, "2", "60");
    wait_for_iteration(&out, 2, &mut child);
    let actors = children_of(child.id());
    assert_eq!(actors.len(), 2, "two actor processes: {actors:?}");
    let victim = actors[0];
    let st = Command::new("kill")
        .args(["-9", &victim.to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    // Its replacement appears while the run goes on.
    let mut seen = actors.clone();
    while child.try_wait().unwrap().is_none() {
        for p in children_of(child.id()) {
            if !seen.contains(&p) {
                seen.push(p);
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "ess failed: {err}");
    assert!(
        err.contains("restarted"),
        "the log says an actor was restarted: {err}"
    );
    assert!(seen.len() >= 3, "a replacement actor was started: {seen:?}");
    // Every iteration completed with the full rollout.
    assert_eq!(summary(&out)["env_steps"], 60 * 400);
    assert_eq!(wait_gone(&seen, 5.0), Vec::<u32>::new(), "left behind");
}

#[test]
fn a_hung_actor_is_detected_by_its_heartbeat_and_replaced() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let mut child = spawn_training_with(&out, "2", "100", &["--set", "run.actor_timeout_s=1"]);
    wait_for_iteration(&out, 1, &mut child);
    let actors = children_of(child.id());
    assert_eq!(actors.len(), 2);
    // SIGSTOP: alive but silent, as a hung actor is.
    let st = Command::new("kill")
        .args(["-STOP", &actors[1].to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "ess failed: {err}");
    assert!(err.contains("sent no heartbeat"), "{err}");
    assert_eq!(summary(&out)["env_steps"], 100 * 400);
    assert_eq!(wait_gone(&actors, 5.0), Vec::<u32>::new(), "left behind");
}

#[test]
fn a_killed_learner_leaves_nothing_that_blocks_the_next_run() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("killed");
    let mut child = spawn_training(&out, "2", "1000");
    wait_for_iteration(&out, 1, &mut child);
    let actors = children_of(child.id());
    assert_eq!(actors.len(), 2);
    // Node names carry the run id, `<learner pid>-<time>`.
    let run_part = format!("-{}-", child.id());
    child.kill().unwrap(); // SIGKILL: no cleanup in the learner
    child.wait().unwrap();
    assert_eq!(
        wait_gone(&actors, 5.0),
        Vec::<u32>::new(),
        "orphaned actors exit by themselves"
    );
    // The next run starts, cleans the dead run's resources and trains.
    let next = tmp.path().join("next");
    let mut args = vec!["train", "--actors", "2", "--out", next.to_str().unwrap()];
    args.extend_from_slice(SMOKE);
    args.extend_from_slice(&["--set", "run.reference_episodes=2"]);
    let o = ess(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(summary(&next)["env_steps"], 2 * 400);
    assert_eq!(
        nodes_named(&run_part).unwrap(),
        vec![],
        "the killed run's iceoryx2 resources were cleaned by the next one"
    );
}

#[test]
fn sigterm_stops_the_learner_and_its_actors() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let mut child = spawn_training(&out, "2", "1000");
    wait_for_iteration(&out, 1, &mut child);
    let actors = children_of(child.id());
    assert_eq!(actors.len(), 2);
    let st = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    let o = child.wait_with_output().unwrap();
    assert!(
        o.status.success(),
        "a SIGTERM stops after the iteration and still writes everything: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(out.join("summary.json").exists());
    assert_eq!(wait_gone(&actors, 5.0), Vec::<u32>::new());
    assert!(actors.iter().all(|&p| !is_running(p)));
}

#[test]
fn a_missing_actor_binary_is_named() {
    let o = Command::new(ess_bin())
        .args(["train", "--actors", "1"])
        .args(SMOKE)
        .env("ESS_ACTOR_BIN", "/nonexistent/ess-actor")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("/nonexistent/ess-actor"), "{err}");
}

#[test]
fn ess_actor_refuses_bad_arguments_naming_them() {
    // (index, n_actors, env, what the error must name)
    for (index, n_actors, env, named) in [("3", "2", ENV, "--index 3"), ("0", "1", "nope", "nope")]
    {
        let o = Command::new(actor_bin())
            .args(["--run-id", "x", "--index", index, "--n-actors", n_actors])
            .args(["--env", env, "--n-modes", "4", "--n-codes", "4"])
            .args(["--seed", "0", "--max-steps", "10"])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{named}");
        assert!(err.contains(named), "{err}");
    }
}

/// Hand-found: `ess` run from a shell that never sourced `.deps/env.sh` worked, but its
/// `ess-actor` children could not load `libmujoco.so` (exit 127, three restarts). Both
/// binaries now carry the library directories in their rpath.
#[test]
fn actors_start_without_the_library_path_of_the_shell() {
    let tmp = tempfile::tempdir().unwrap();
    let o = Command::new(ess_bin())
        .args([
            "train",
            "--actors",
            "1",
            "--out",
            tmp.path().to_str().unwrap(),
        ])
        .args(SMOKE)
        .args(["--set", "run.reference_episodes=2"])
        .env_remove("LD_LIBRARY_PATH")
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Hand-found: an actor that died at start was reported as "exited (exit status: 127)",
/// its own message long scrolled away; the error now quotes its last output.
#[test]
fn an_actor_that_dies_names_its_cause_in_the_error() {
    use std::os::unix::fs::PermissionsExt;
    let tmp = tempfile::tempdir().unwrap();
    let fake = tmp.path().join("ess-actor");
    let msg = "ess-actor: error while loading shared libraries: libfake.so.1: cannot open shared object file";
    std::fs::write(&fake, format!("#!/bin/sh\necho '{msg}' >&2\nexit 127\n")).unwrap();
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    let o = Command::new(ess_bin())
        .args(["train", "--actors", "1", "--out"])
        .arg(tmp.path().join("run"))
        .args(SMOKE)
        .env("ESS_ACTOR_BIN", &fake)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    let last = err
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .unwrap_or("");
    assert!(last.contains("exit status: 127"), "last line: {last}");
    assert!(last.contains("libfake.so.1"), "last line: {last}");
}

/// Actor processes' mid-episode states travel into checkpoints and back: a run with two
/// actor processes stopped by SIGTERM and resumed ends bit-identical to one never
/// stopped (before, its actors restarted their episodes and the numbers drifted).
#[test]
fn a_run_with_actor_processes_resumes_bit_identical_to_one_never_stopped() {
    let tmp = tempfile::tempdir().unwrap();
    let (whole, parts) = (tmp.path().join("whole"), tmp.path().join("parts"));
    let mut extra = STEADY_SET.to_vec();
    extra.extend(["--seed", "5", "--set", "run.checkpoint_every=1"]);
    let o = spawn_training_with(&whole, "2", "12", &extra)
        .wait_with_output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let mut child = spawn_training_with(&parts, "2", "12", &extra);
    wait_for_iteration(&parts, 3, &mut child);
    let st = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stopped = summary(&parts);
    assert_eq!(stopped["interrupted"], true, "{stopped}");
    assert!(stopped["iterations"].as_u64().unwrap() < 12, "{stopped}");

    let o = Command::new(ess_bin())
        .args(["train", "--resume", parts.to_str().unwrap()])
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(!err.contains("no actor states"), "{err}");
    assert_eq!(
        metrics_without_timings(&whole),
        metrics_without_timings(&parts)
    );
    let (a, b) = (summary(&whole), summary(&parts));
    for key in ["nmi", "ent", "normalized_reward", "env_steps", "prior"] {
        assert_eq!(a[key], b[key], "summary.json `{key}`");
    }
    let policy =
        |d: &Path| std::fs::read(d.join("checkpoints/iter-000012/policy.safetensors")).unwrap();
    assert!(policy(&whole) == policy(&parts), "final policies differ");
}
