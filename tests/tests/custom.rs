//! A user's own task and demonstrations: the arm3 task file (`deploy/tasks/arm3`), its
//! demonstrations recorded with the upstream Python `minari` + `gymnasium`
//! (`tests/fixtures/arm3/record.py`; the committed fixture is its output), imported
//! from Minari and from `.npz`, trained on, and bad input refused.

use ess_tests::{SMOKE, ess};
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn task() -> String {
    format!(
        "task:{}",
        repo().join("deploy/tasks/arm3/task.toml").display()
    )
}

fn minari_dir() -> String {
    repo()
        .join("tests/fixtures/arm3/minari/ess/arm3-v0")
        .display()
        .to_string()
}

fn npz() -> String {
    repo()
        .join("tests/fixtures/arm3/arm3.npz")
        .display()
        .to_string()
}

fn import(args: &[&str]) -> std::process::Output {
    let mut all = vec!["demos", "import"];
    all.extend_from_slice(args);
    ess(&all)
}

/// `ess demos inspect --values`: the metadata and every value.
fn inspect(path: &Path) -> (serde_json::Value, serde_json::Value) {
    let out = ess(&["demos", "inspect", &path.display().to_string(), "--values"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).expect("utf8");
    let (meta, values) = text.trim_end().rsplit_once('\n').expect("two parts");
    (
        serde_json::from_str(meta).expect("meta"),
        serde_json::from_str(values).expect("values"),
    )
}

/// The fixture's arrays as numpy wrote them, read here without Ess's importer.
struct Expected {
    obs: Vec<f32>,
    next: Vec<f32>,
    act: Vec<f32>,
    rew: Vec<f64>,
    ends: Vec<i64>,
    modes: Vec<i64>,
}

fn expected() -> Expected {
    let mut z = npyz::npz::NpzArchive::open(npz()).expect("npz");
    let mut f32s = |n: &str| -> Vec<f32> { z.by_name(n).unwrap().unwrap().into_vec().unwrap() };
    let (obs, next, act) = (
        f32s("observations"),
        f32s("next_observations"),
        f32s("actions"),
    );
    let mut z = npyz::npz::NpzArchive::open(npz()).expect("npz");
    let mut ints = |n: &str| -> Vec<i64> { z.by_name(n).unwrap().unwrap().into_vec().unwrap() };
    let (ends, modes) = (ints("episode_ends"), ints("episode_modes"));
    let mut z = npyz::npz::NpzArchive::open(npz()).expect("npz");
    let rew: Vec<f64> = z.by_name("rewards").unwrap().unwrap().into_vec().unwrap();
    Expected {
        obs,
        next,
        act,
        rew,
        ends,
        modes,
    }
}

fn f32s(v: &serde_json::Value) -> Vec<f32> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap() as f32)
        .collect()
}

fn ints(v: &serde_json::Value) -> Vec<i64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_i64().unwrap())
        .collect()
}

fn check_round_trip(values: &serde_json::Value, e: &Expected) {
    let u = &values["unlabeled"];
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&f32s(&u["obs"])), bits(&e.obs), "obs");
    assert_eq!(bits(&f32s(&u["next_obs"])), bits(&e.next), "next_obs");
    assert_eq!(bits(&f32s(&u["act"])), bits(&e.act), "act");
    let rew: Vec<f32> = e.rew.iter().map(|&r| r as f32).collect();
    assert_eq!(bits(&f32s(&u["reward"])), bits(&rew), "reward");
    let (mut row_mode, mut row_ep) = (Vec::new(), Vec::new());
    let mut start = 0;
    for (i, (&end, &m)) in e.ends.iter().zip(&e.modes).enumerate() {
        row_mode.extend(std::iter::repeat_n(m, (end - start) as usize));
        row_ep.extend(std::iter::repeat_n(i as i64, (end - start) as usize));
        start = end;
    }
    assert_eq!(ints(&u["mode"]), row_mode, "mode");
    assert_eq!(ints(&u["episode"]), row_ep, "episode");
}

#[test]
fn minari_and_npz_fixtures_import_bit_for_bit() {
    let d = tempfile::tempdir().unwrap();
    let e = expected();
    let (a, b) = (
        d.path().join("new/dir/a.safetensors"),
        d.path().join("b.safetensors"),
    );
    let out = import(&[
        &minari_dir(),
        "--env",
        &task(),
        "--labels-field",
        "infos/mode",
        "--out",
        &a.display().to_string(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = import(&[&npz(), "--env", &task(), "--out", &b.display().to_string()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (meta_a, va) = inspect(&a);
    let (meta_b, vb) = inspect(&b);
    check_round_trip(&va, &e);
    check_round_trip(&vb, &e);
    assert_eq!(va, vb, "Minari and npz imports differ");
    assert_eq!(
        meta_a["unlabeled_episodes_per_mode"],
        serde_json::json!([100, 100, 5])
    );
    assert_eq!(meta_a["imbalance_ratio"], serde_json::json!(20.0));
    // 2% of 10250 steps over 3 modes: ceil(68.33) = 69 labeled steps each.
    assert_eq!(
        meta_a["labeled_steps_per_mode"],
        serde_json::json!([69, 69, 69])
    );
    let src = &meta_a["source"];
    assert_eq!(src["format"], "minari");
    assert_eq!(src["episodes"], 205);
    assert_eq!(src["options"]["labels_field"], "infos/mode");
    assert_eq!(src["sha256"].as_str().unwrap().len(), 64);
    assert_eq!(meta_b["source"]["format"], "npz");
    // The labeled rows are rows of the data with their episode's mode.
    let l = &vb["labeled"];
    let obs = f32s(&l["obs"]);
    for (row, &m) in ints(&l["mode"]).iter().enumerate() {
        let at = e
            .obs
            .chunks(8)
            .position(|r| r == &obs[row * 8..row * 8 + 8])
            .expect("labeled row in the data");
        let ep = e.ends.iter().position(|&end| (at as i64) < end).unwrap();
        assert_eq!(e.modes[ep], m, "labeled row {row}");
    }
}

/// Runs an import expected to fail: exit 2, one line naming `want`, nothing written.
fn refused(args: &[&str], want: &str) {
    let d = tempfile::tempdir().unwrap();
    let out_file = d.path().join("out.safetensors");
    let mut all = args.to_vec();
    let o = out_file.display().to_string();
    all.extend(["--out", &o]);
    let out = import(&all);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{want}: {err}");
    assert_eq!(err.trim().lines().count(), 1, "{want}: {err}");
    assert!(err.contains(want), "{want:?} not in {err}");
    assert!(!out_file.exists(), "{want}: a file was written");
}

/// An npz written here (by npyz) with `obs` rows of width 8, actions of width 3.
fn write_npz(dir: &Path, obs: &[f32], act: &[f32], ends: &[i64], modes: &[i64]) -> String {
    use npyz::WriterBuilder;
    let p = dir.join("bad.npz");
    let mut w = npyz::npz::NpzWriter::create(&p).unwrap();
    let n = (act.len() / 3) as u64;
    let mut put = |name: &str, shape: &[u64], v: &[f32]| {
        let mut a = w
            .array(name, Default::default())
            .unwrap()
            .default_dtype()
            .shape(shape)
            .begin_nd()
            .unwrap();
        a.extend(v.iter().copied()).unwrap();
        a.finish().unwrap();
    };
    put("observations", &[n, 8], &obs[..n as usize * 8]);
    put("next_observations", &[n, 8], &obs[8..8 + n as usize * 8]);
    put("actions", &[n, 3], act);
    let mut put_i = |name: &str, v: &[i64]| {
        let mut a = w
            .array(name, Default::default())
            .unwrap()
            .default_dtype()
            .shape(&[v.len() as u64])
            .begin_nd()
            .unwrap();
        a.extend(v.iter().copied()).unwrap();
        a.finish().unwrap();
    };
    put_i("episode_ends", ends);
    put_i("episode_modes", modes);
    p.display().to_string()
}

#[test]
fn bad_demonstrations_are_one_line_exit_2_and_nothing_written() {
    let d = tempfile::tempdir().unwrap();
    let t = task();
    // Obs width 7 for a task whose observation has 8 entries.
    let narrow = d.path().join("narrow.toml");
    std::fs::write(
        &narrow,
        format!("mjcf = \"{}\"\nmax_steps = 50\n[[obs]]\nqpos = \"*\"\n[[obs]]\nqvel = \"*\"\n[[obs]]\nbody_pos = \"fingertip\"\ntake = [0]\n",
            repo().join("deploy/tasks/arm3/arm3.xml").display()),
    )
    .unwrap();
    let narrow_env = format!("task:{}", narrow.display());
    refused(
        &[&npz(), "--env", &narrow_env, "--n-modes", "3"],
        "observations has shape [10250, 8]: width 8, but the env's is 7",
    );
    refused(
        &[
            &minari_dir(),
            "--env",
            &narrow_env,
            "--n-modes",
            "3",
            "--labels-field",
            "infos/mode",
        ],
        "episode_0: observations has shape [51, 8]: width 8, but the env's is 7",
    );
    // Non-finite values, empty episodes, labels out of range.
    let obs: Vec<f32> = (0..8 * 5).map(|i| i as f32 * 0.01).collect();
    let mut act = vec![0.1f32; 12];
    act[7] = f32::NAN;
    let p = write_npz(d.path(), &obs, &act, &[2, 4], &[0, 1]);
    refused(
        &[&p, "--env", &t],
        "episode 1 (rows 2..4): actions row 0 holds a non-finite value NaN",
    );
    let act = vec![0.1f32; 12];
    let p = write_npz(d.path(), &obs, &act, &[2, 2, 4], &[0, 1, 1]);
    refused(&[&p, "--env", &t], "episode_ends[1] = 2");
    let p = write_npz(d.path(), &obs, &act, &[2, 4], &[0, 7]);
    refused(
        &[&p, "--env", &t],
        "episode 1 (rows 2..4): label 7 is out of range",
    );
    // Fewer than two modes labeled; a mode without any label.
    let p = write_npz(d.path(), &obs, &act, &[2, 4], &[1, -1]);
    refused(&[&p, "--env", &t], "1 mode(s) labeled");
    let p = write_npz(d.path(), &obs, &act, &[2, 4], &[0, 1]);
    refused(&[&p, "--env", &t], "mode 2 of 0..3 has no labeled episode");
    let p = write_npz(d.path(), &obs, &act, &[1, 2, 4], &[0, 1, 2]);
    refused(
        &[&p, "--env", &t, "--label-ratio", "0"],
        "label ratio 0 must be in (0, 1]",
    );
    // A label field that does not exist; a labels file with a bad line.
    refused(
        &[&minari_dir(), "--env", &t, "--labels-field", "infos/skill"],
        "episode_0: no dataset or attribute \"infos/skill\"",
    );
    let lf = d.path().join("labels.txt");
    std::fs::write(&lf, "0\n1\nleft\n").unwrap();
    refused(
        &[
            &npz(),
            "--env",
            &t,
            "--labels-file",
            &lf.display().to_string(),
        ],
        "labels.txt: line 3: \"left\" is not an integer label",
    );
    // A task file MuJoCo cannot compile; a source that is not a dataset.
    let broken = d.path().join("broken.toml");
    std::fs::write(d.path().join("broken.xml"), "<mujoco><worldbody><body>").unwrap();
    std::fs::write(
        &broken,
        "mjcf = \"broken.xml\"\nmax_steps = 5\n[[obs]]\nqpos = \"*\"\n",
    )
    .unwrap();
    refused(
        &[
            &npz(),
            "--env",
            &format!("task:{}", broken.display()),
            "--n-modes",
            "3",
        ],
        "broken.xml: MuJoCo: ",
    );
    refused(
        &[&d.path().display().to_string(), "--env", &t],
        "not a Minari dataset",
    );
}

#[test]
fn an_existing_output_is_kept_without_force() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("demos.safetensors");
    std::fs::write(&out, "precious").unwrap();
    let o = out.display().to_string();
    let r = import(&[&npz(), "--env", &task(), "--out", &o]);
    assert_eq!(r.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&r.stderr).contains("pass --force"));
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "precious");
}

#[test]
fn a_task_file_trains_with_actor_processes_and_threads_on_imported_demos() {
    let d = tempfile::tempdir().unwrap();
    let demos = d.path().join("demos.safetensors");
    let ds = demos.display().to_string();
    let out = import(&[&npz(), "--env", &task(), "--out", &ds]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for (name, transport) in [("proc", "processes"), ("thr", "threads")] {
        let run = d.path().join(name).display().to_string();
        let env_set = format!("env.name=\"{}\"", task());
        let demos_set = format!("demos.path=\"{ds}\"");
        let transport_set = format!("run.transport=\"{transport}\"");
        let mut args = vec![
            "train",
            "--set",
            &env_set,
            "--set",
            "env.n_modes=3",
            "--set",
            &demos_set,
            "--set",
            &transport_set,
            "--set",
            "run.actors=2",
            "--out",
            &run,
        ];
        args.extend_from_slice(SMOKE);
        let r = ess(&args);
        let stdout = String::from_utf8_lossy(&r.stdout);
        assert!(
            r.status.success(),
            "{name}: {}{stdout}",
            String::from_utf8_lossy(&r.stderr)
        );
        let s: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(Path::new(&run).join("summary.json")).unwrap(),
        )
        .unwrap();
        assert!(s["nmi"].as_f64().unwrap().is_finite(), "{s}");
        assert_eq!(s["env"], task().as_str());
        assert!(stdout.contains("normalized reward"), "{stdout}");
        // Replay re-simulates a recorded episode of the task file exactly.
        let log = Path::new(&run).join("run.mcap").display().to_string();
        let r = ess(&["replay", &log, "--episode", "0"]);
        let text = String::from_utf8_lossy(&r.stdout);
        assert!(
            r.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&r.stderr)
        );
        assert!(
            text.contains("max |obs - recorded|       0.000e0"),
            "{name}: {text}"
        );
    }
}

#[test]
fn training_a_task_without_or_with_unfit_demonstrations_is_one_line_exit_2() {
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("run").display().to_string();
    let env_set = format!("env.name=\"{}\"", task());
    let r = ess(&[
        "train",
        "--set",
        &env_set,
        "--set",
        "env.n_modes=3",
        "--out",
        &run,
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    // One error line (after `ess train`'s own header line).
    let errors = err.lines().filter(|l| l.starts_with("error")).count();
    assert_eq!(errors, 1, "{err}");
    assert!(
        err.contains("is a task file") && err.contains("ess demos import"),
        "{err}"
    );
    // Demonstrations made for another env (traj2d) fed to the task.
    let demos = d.path().join("traj2d.safetensors").display().to_string();
    let mut gen_args = vec!["demos", "generate", "--out", &demos];
    gen_args.extend_from_slice(&["--set", "demos.majority_episodes=4"]);
    assert!(ess(&gen_args).status.success());
    let demos_set = format!("demos.path=\"{demos}\"");
    let r = ess(&[
        "train",
        "--set",
        &env_set,
        "--set",
        "env.n_modes=3",
        "--set",
        &demos_set,
        "--out",
        &run,
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("dataset is for env `traj2d`"), "{err}");
}
