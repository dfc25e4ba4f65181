//! `ess experiment SPEC`: a bad spec is refused with one line naming the file and the
//! field (exit 2) before anything runs; a grid runs through the job queue, reports,
//! and a second invocation runs only the cells that have not finished.
//! (`bench/slurm_grid.sh` runs the same grid through a real Slurm.)

use ess_tests::ess;
use std::path::Path;

const GRID: &str = r#"
name = "t"
presets = ["gail", "ess-infogail"]
envs = ["traj2d"]
seeds = [3]
set = ["run.iterations=2", "run.rollout_steps=400", "disc.steps=3", "disc.batch=64",
       "ppo.epochs=2", "ppo.minibatch=200", "run.eval_episodes=2", "run.eval_every=0",
       "demos.majority_episodes=20", "run.reference_episodes=2", "run.actors=1",
       "run.transport=\"threads\"", "run.torch_threads=1"]
rows = "preset"
columns = "env"
metrics = ["nmi", "ent", "prior_tv"]
"#;

fn write_spec(dir: &Path, text: &str) -> String {
    let p = dir.join("spec.toml");
    std::fs::write(&p, text).unwrap();
    p.display().to_string()
}

#[test]
fn bad_specs_are_refused_naming_the_field_and_nothing_runs() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    let out_s = out.display().to_string();
    for (from, to, must_name) in [
        (r#"presets = ["gail", "#, r#"presets = ["gial", "#, "gial"),
        (r#"envs = ["traj2d"]"#, r#"envs = ["traj3d"]"#, "traj3d"),
        ("seeds = [3]", "seeds = [3, 4, 3]", "`seeds` lists 3 twice"),
        ("seeds = [3]", "seeds = []", "`seeds` is empty"),
        (
            r#"presets = ["gail", "ess-infogail"]"#,
            "presets = []",
            "`presets` is empty",
        ),
        ("\"disc.steps=3\"", "\"disc.stepz=3\"", "disc.stepz"),
        (r#""prior_tv"]"#, r#""nmii"]"#, "nmii"),
        (
            "rows = \"preset\"\ncolumns = \"env\"",
            "rows = \"env\"\ncolumns = \"variant\"",
            "`presets` has 2 values",
        ),
        ("columns = \"env\"", "columns = \"preset\"", "both preset"),
        ("name = \"t\"", "name = \"t\"\nbogus = 1", "bogus"),
    ] {
        assert!(GRID.contains(from), "{from}");
        let spec = write_spec(d.path(), &GRID.replace(from, to));
        let o = ess(&["experiment", &spec, "--out", &out_s]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{to}: {err}");
        let lines: Vec<&str> = err.lines().collect();
        assert_eq!(lines.len(), 1, "{to}: one line: {err}");
        assert!(
            lines[0].contains("spec.toml"),
            "{to}: names the file: {err}"
        );
        assert!(
            lines[0].contains(must_name),
            "{to}: names `{must_name}`: {err}"
        );
        assert!(!out.exists(), "{to}: nothing may be created");
    }
    let spec = write_spec(d.path(), GRID);
    let o = ess(&["experiment", &spec, "--out", &out_s, "--cell", "2"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--cell 2"));
}

fn cell_summary(out: &Path, cell: &str) -> serde_json::Value {
    let p = out.join("jobs").join(cell).join("summary.json");
    serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap()
}

#[test]
fn a_grid_runs_reports_and_reruns_only_unfinished_cells() {
    let d = tempfile::tempdir().unwrap();
    let spec = write_spec(d.path(), GRID);
    let out = d.path().join("out");
    let out_s = out.display().to_string();
    let o = ess(&["experiment", &spec, "--out", &out_s, "--cores", "2"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("2 of 2 cells finished"), "{report}");
    assert!(report.contains("| ess-infogail | "), "{report}");
    // The paper's Table 1 value is printed beside ours.
    assert!(report.contains("[paper 0.910]"), "{report}");
    let first = cell_summary(&out, "ess-infogail.traj2d.s3");
    assert_eq!(first["seed"], 3);
    assert!(first["prior_tv"].as_f64().unwrap() >= 0.0);

    // Everything finished: nothing runs again.
    let o = ess(&["experiment", &spec, "--out", &out_s]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("2 cells finished before, 0 now"));

    // A cell whose run is gone runs again, alone, to the same numbers.
    std::fs::remove_dir_all(out.join("jobs/ess-infogail.traj2d.s3")).unwrap();
    let gail_before = cell_summary(&out, "gail.traj2d.s3")["wall_seconds"].clone();
    let o = ess(&["experiment", &spec, "--out", &out_s]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("1 cells finished before, 1 now"), "{err}");
    let again = cell_summary(&out, "ess-infogail.traj2d.s3");
    assert_eq!(again["nmi"], first["nmi"]);
    assert_eq!(again["prior"], first["prior"]);
    assert_eq!(
        cell_summary(&out, "gail.traj2d.s3")["wall_seconds"],
        gail_before
    );
}
