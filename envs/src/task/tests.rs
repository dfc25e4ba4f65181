use std::path::{Path, PathBuf};

use super::*;
use crate::env::conformance::{assert_random_controls_raise_no_warning, check_env};
use crate::make_plain_env;

fn arm3() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/tasks/arm3/task.toml")
}

fn load_arm3() -> TaskEnv {
    TaskEnv::load(&arm3(), 3).expect("arm3 task")
}

/// A task file in a temp dir beside a copy of arm3.xml (or `xml` when given).
fn write_task(toml: &str, xml: Option<&str>) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("tmp");
    let model = match xml {
        Some(x) => x.to_owned(),
        None => std::fs::read_to_string(arm3().with_file_name("arm3.xml")).expect("arm3.xml"),
    };
    std::fs::write(dir.path().join("arm3.xml"), model).expect("write xml");
    let path = dir.path().join("task.toml");
    std::fs::write(&path, toml).expect("write toml");
    (dir, path)
}

const HEAD: &str = "mjcf = \"arm3.xml\"\nmax_steps = 20\n";

fn task_err(body: &str, n_modes: usize) -> String {
    let (_dir, path) = write_task(&format!("{HEAD}{body}"), None);
    let err = TaskEnv::load(&path, n_modes).expect_err("a bad task file was accepted");
    assert!(matches!(err, EnvError::Task { .. }), "{err}");
    let msg = err.to_string();
    assert!(msg.contains("task.toml") && !msg.contains('\n'), "{msg}");
    msg
}

#[test]
fn the_arm3_task_passes_the_conformance_suite() {
    check_env("arm3 task", &|| Box::new(load_arm3()));
    check_env("arm3 via make_plain_env", &|| {
        make_plain_env(&format!("task:{}", arm3().display()), 3).expect("arm3")
    });
}

#[test]
fn the_arm3_task_has_the_spaces_its_file_describes() {
    let env = load_arm3();
    let s = env.spec();
    // qpos 3 + qvel 3 + fingertip x, y.
    assert_eq!(
        (s.obs_dim, s.act_dim, s.n_modes, s.max_steps),
        (8, 3, 3, 50)
    );
    assert!(s.name.starts_with("task:") && s.name.ends_with("task.toml"));
    assert!(env.has_mode_rewards());
    let mut env = load_arm3();
    assert_random_controls_raise_no_warning(&mut env, 4, |e| {
        crate::mujoco::warning_counts(&e.sim.data)
    });
}

#[test]
fn observation_pieces_read_the_named_state() {
    let mut env = load_arm3();
    let mut obs = vec![0.0f32; 8];
    env.reset(3, &mut obs).expect("reset");
    for _ in 0..5 {
        env.step(&[0.5, -0.3, 0.8], &mut obs).expect("step");
    }
    let d = &env.sim.data;
    let want: Vec<f32> = d
        .qpos()
        .iter()
        .chain(d.qvel())
        .map(|x| *x as f32)
        .chain(d.xpos()[4][..2].iter().map(|x| *x as f32))
        .collect();
    assert_eq!(obs, want);
    // The fingertip is at the sum of the three links' directions.
    let q = d.qpos();
    let (a1, a2, a3) = (q[0], q[0] + q[1], q[0] + q[1] + q[2]);
    let x = -0.1 * (a1.sin() + a2.sin() + a3.sin());
    let y = 0.1 * (a1.cos() + a2.cos() + a3.cos());
    assert!((f64::from(obs[6]) - x).abs() < 1e-6 && (f64::from(obs[7]) - y).abs() < 1e-6);
}

#[test]
fn mode_rewards_are_the_weighted_terms_of_each_mode() {
    let mut env = load_arm3();
    let mut obs = vec![0.0f32; 8];
    env.reset(0, &mut obs).expect("reset");
    env.step(&[1.0, 0.0, -1.0], &mut obs).expect("step");
    let tip = [f64::from(obs[6]), f64::from(obs[7]), 0.0];
    let ctrl_sq = 2.0;
    let mut r = [0.0f32; 3];
    env.mode_rewards(&mut r);
    let targets = [[-0.17, 0.12], [0.0, 0.25], [0.17, 0.12]];
    for (k, t) in targets.iter().enumerate() {
        let d =
            ((tip[0] - t[0]).powi(2) + (tip[1] - t[1]).powi(2) + env.sim.data.xpos()[4][2].powi(2))
                .sqrt();
        let want = -d - 0.001 * ctrl_sq;
        assert!(
            (f64::from(r[k]) - want).abs() < 1e-5,
            "mode {k}: {} vs {want}",
            r[k]
        );
    }
}

#[test]
fn a_task_without_modes_has_no_mode_rewards_and_takes_any_mode_count() {
    let (_dir, path) = write_task(&format!("{HEAD}[[obs]]\nqpos = \"*\"\n"), None);
    for k in [2, 5] {
        let env = TaskEnv::load(&path, k).expect("task");
        assert!(!env.has_mode_rewards());
        let mut r = vec![1.0f32; k];
        env.mode_rewards(&mut r);
        assert!(r.iter().all(|x| *x == 0.0));
    }
}

#[test]
fn slices_clips_and_termination_do_what_the_file_says() {
    let body = "[[obs]]\nqpos = \"*\"\ndrop = [0]\n[[obs]]\nqvel = \"elbow\"\nclip = 0.01\n\
                [[obs]]\nsensor = \"tip\"\ntake = [1]\n[[terminate]]\nquantity = \"body_pos.fingertip.y\"\nrange = [0.25, 1.0]\n";
    let (_dir, path) = write_task(&format!("{HEAD}{body}"), None);
    let mut env = TaskEnv::load(&path, 2).expect("task");
    assert_eq!(env.spec().obs_dim, 4);
    let mut obs = vec![0.0f32; 4];
    env.reset(1, &mut obs).expect("reset");
    let out = env.step(&[1.0, 1.0, 1.0], &mut obs).expect("step");
    let d = &env.sim.data;
    assert_eq!(obs[..2], [d.qpos()[1] as f32, d.qpos()[2] as f32]);
    assert_eq!(obs[2], d.qvel()[1].clamp(-0.01, 0.01) as f32);
    assert_eq!(obs[3], d.xpos()[4][1] as f32);
    // The arm starts straight ahead (tip y = 0.3) and bends: y leaves (0.25, 1) soon.
    let mut steps = 1;
    let mut out = out;
    while !out.done() {
        out = env.step(&[1.0, 1.0, 1.0], &mut obs).expect("step");
        steps += 1;
    }
    assert!(out.terminated && steps < 20, "{out:?} after {steps}");
}

#[test]
fn bad_task_files_are_one_line_naming_the_file_and_key() {
    let cases: &[(&str, usize, &str)] = &[
        (
            "[[obs]]\nqpos = \"knee\"\n",
            3,
            "obs[0]: the model has no joint named \"knee\"",
        ),
        (
            "[[obs]]\nsensor = \"touch\"\n",
            3,
            "obs[0]: the model has no sensor named \"touch\"",
        ),
        (
            "[[obs]]\nbody_pos = \"hand\"\n",
            3,
            "obs[0]: the model has no body named \"hand\"",
        ),
        (
            "[[obs]]\nqpos = \"*\"\nqvel = \"*\"\n",
            3,
            "obs[0]: names 2 sources",
        ),
        ("[[obs]]\ntake = [0]\n", 3, "obs[0]: names no source"),
        (
            "[[obs]]\nqpos = \"*\"\ntake = [3]\n",
            3,
            "index 3 is out of range",
        ),
        (
            "[[obs]]\nqpos = \"*\"\ntake = [0]\ndrop = [1]\n",
            3,
            "both take and drop",
        ),
        ("[[obs]]\nqpos = \"*\"\nclip = -1.0\n", 3, "clip = -1"),
        ("obs = []\n", 3, "at least one piece"),
        (
            "[[obs]]\nqpos = \"*\"\nbogus = 1\n",
            3,
            "unknown field `bogus`",
        ),
        (
            "frame_skip = 0\n[[obs]]\nqpos = \"*\"\n",
            3,
            "frame_skip = 0",
        ),
        (
            "reset_noise = -1.0\n[[obs]]\nqpos = \"*\"\n",
            3,
            "reset_noise = -1",
        ),
        ("[[obs]]\nqpos = \"*\"\n", 1, "n_modes = 1"),
        (
            "[[obs]]\nqpos = \"*\"\n[[terminate]]\nquantity = \"body_pos.link1\"\nrange = [0, 1]\n",
            3,
            "terminate[0]: quantity \"body_pos.link1\": body_pos of \"link1\" has 3 entries",
        ),
        (
            "[[obs]]\nqpos = \"*\"\n[[terminate]]\nquantity = \"qpos.elbow\"\nrange = [1, 0]\n",
            3,
            "terminate[0].range = [1, 0]",
        ),
        (
            "[[obs]]\nqpos = \"*\"\n[[terminate]]\nquantity = \"height\"\nrange = [0, 1]\n",
            3,
            "terminate[0]: quantity \"height\": expected ctrl_sq or SOURCE.NAME",
        ),
        (
            "[[obs]]\nqpos = \"*\"\n[[modes]]\nname = \"a\"\nreward = [{ quantity = \"ctrl_sq\", weight = 1.0 }]\n",
            3,
            "the file scores 1 modes but the run has n_modes = 3",
        ),
        (
            "[[obs]]\nqpos = \"*\"\n[[modes]]\nname = \"a\"\nreward = [{ distance = \"fingertip\", weight = 1.0 }]\n",
            3,
            "modes[0].reward[0]: a distance term needs exactly one of to, to_body",
        ),
        (
            "[[obs]]\nqpos = \"*\"\n[[modes]]\nname = \"a\"\nreward = [{ distance = \"toe\", to = [0, 0, 0], weight = 1.0 }]\n[[modes]]\nname = \"b\"\nreward = [{ quantity = \"ctrl_sq\", weight = 1.0 }]\n",
            2,
            "modes[0].reward[0]: the model has no body named \"toe\"",
        ),
    ];
    for (body, k, want) in cases {
        let msg = task_err(body, *k);
        assert!(msg.contains(want), "{want:?} not in: {msg}");
    }
}

#[test]
fn a_missing_field_names_its_line() {
    let msg = task_err("[[obs]]\nqpos = 3\n", 3);
    assert!(msg.contains("line 4") && msg.contains("qpos"), "{msg}");
}

#[test]
fn mjcf_that_mujoco_cannot_compile_passes_its_message_through() {
    let (_d, path) = write_task(
        &format!("{HEAD}[[obs]]\nqpos = \"*\"\n"),
        Some("<mujoco><worldbody><body>"),
    );
    let msg = TaskEnv::load(&path, 2).expect_err("bad xml").to_string();
    assert!(
        msg.contains("arm3.xml: MuJoCo: ") && msg.contains("XML") && !msg.contains('\n'),
        "{msg}"
    );
    let unlimited = "<mujoco><worldbody><body><joint name=\"j\" type=\"hinge\"/><geom size=\"0.1\"/></body></worldbody>\
                     <actuator><motor name=\"m\" joint=\"j\"/></actuator></mujoco>";
    let (_d, path) = write_task(&format!("{HEAD}[[obs]]\nqpos = \"*\"\n"), Some(unlimited));
    let msg = TaskEnv::load(&path, 2)
        .expect_err("no ctrlrange")
        .to_string();
    assert!(
        msg.contains("actuator 0 (\"m\") needs a finite ctrlrange"),
        "{msg}"
    );
    let (_d, path) = write_task(
        "mjcf = \"nope.xml\"\nmax_steps = 5\n[[obs]]\nqpos = \"*\"\n",
        None,
    );
    let msg = TaskEnv::load(&path, 2)
        .expect_err("missing xml")
        .to_string();
    assert!(msg.contains("nope.xml"), "{msg}");
    let msg = TaskEnv::load(Path::new("/nonexistent/task.toml"), 2)
        .expect_err("no file")
        .to_string();
    assert!(msg.contains("/nonexistent/task.toml: cannot read"), "{msg}");
}

#[test]
fn make_env_refuses_a_task_file_it_has_no_expert_for() {
    let Err(err) = crate::make_env(&format!("task:{}", arm3().display()), 3) else {
        panic!("a task file got an expert");
    };
    assert!(err.to_string().contains("ess demos import"), "{err}");
}

#[test]
fn devices_fifos_and_huge_files_are_refused_not_read() {
    // A job spec names its task file by path on the server: `/dev/zero` used to be read
    // until memory ran out, and a FIFO or `/dev/stdin` blocked the server's worker.
    let dir = tempfile::tempdir().expect("tmp");
    let fifo = dir.path().join("fifo.toml");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .expect("mkfifo");
    assert!(made.success());
    for path in [PathBuf::from("/dev/zero"), fifo.clone()] {
        // In a thread with a deadline, so that a read that blocks fails this test in
        // seconds instead of hanging the suite until its 10-minute kill.
        let (tx, rx) = std::sync::mpsc::channel();
        let p = path.clone();
        std::thread::spawn(move || {
            let _ = tx.send(TaskEnv::load(&p, 3).map(|_| ()).map_err(|e| e.to_string()));
        });
        let got = rx.recv_timeout(std::time::Duration::from_secs(20));
        let msg = got
            .unwrap_or_else(|_| panic!("reading {} blocked", path.display()))
            .expect_err("read");
        assert!(msg.contains("not a regular file"), "{msg}");
    }
    let big = dir.path().join("big.toml");
    let line = "# padding\n".repeat(1 + file::MAX_TASK_FILE_BYTES as usize / 10);
    std::fs::write(&big, format!("{HEAD}{line}")).expect("write");
    let msg = TaskEnv::load(&big, 3).expect_err("huge").to_string();
    assert!(msg.contains("big.toml: cannot read: larger than"), "{msg}");
}
