//! A run's TensorBoard event files (`<run>/tb/`), read by TensorBoard's own loader
//! (`tensorboard.backend.event_processing.event_accumulator`, the `tensorboard` wheel
//! from PyPI in `.deps/pytest`): every number of `metrics.csv` at its env steps, the
//! evaluations per code, the config as text and the figures as images. And a run whose
//! `tb` cannot be created still trains and says so once.

use ess_tests::{SMOKE, ess, pytest_path, python};
use serde_json::Value;
use std::path::Path;

/// Loads the event files of a directory with TensorBoard's accumulator and prints
/// every scalar series, the image tags with their sizes and the text tags as JSON.
const LOAD_WITH_TENSORBOARD: &str = r#"
import json, sys
from tensorboard.backend.event_processing import event_accumulator as ea
acc = ea.EventAccumulator(sys.argv[1], size_guidance={ea.SCALARS: 0, ea.IMAGES: 0, ea.TENSORS: 0})
acc.Reload()
tags = acc.Tags()
out = {
    "scalars": {t: [[e.step, e.value] for e in acc.Scalars(t)] for t in tags["scalars"]},
    "images": {t: [[e.step, e.width, e.height] for e in acc.Images(t)] for t in tags["images"]},
    "texts": {t: [e.tensor_proto.string_val[0].decode() for e in acc.Tensors(t)] for t in tags["tensors"]},
}
json.dump(out, sys.stdout)
"#;

fn load(tb: &Path) -> Value {
    let out = python(LOAD_WITH_TENSORBOARD, &[tb.as_os_str()]);
    assert!(
        out.status.success(),
        "TensorBoard's loader (PYTHONPATH {}; `bash scripts/bootstrap.sh --nextest` installs it) failed: {}",
        pytest_path().display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("json")
}

/// The value of `tag` at `step`, if logged there.
fn at(scalars: &Value, tag: &str, step: u64) -> Option<f64> {
    scalars[tag]
        .as_array()?
        .iter()
        .find_map(|p| (p[0].as_u64() == Some(step)).then(|| p[1].as_f64().expect("value")))
}

/// The tag whose part after the slash is `column` (each tag is `<group>/<column>`).
fn tag_of(scalars: &Value, column: &str) -> Option<String> {
    let map = scalars.as_object().expect("scalars");
    map.keys()
        .find(|t| t.rsplit('/').next() == Some(column))
        .cloned()
}

/// `metrics.csv`'s rows as (header, rows of cells).
fn csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).expect("metrics.csv");
    let mut lines = text.lines();
    let head: Vec<String> = lines
        .next()
        .expect("header")
        .split(',')
        .map(String::from)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    (head, rows)
}

/// Equal to the CSV's printed value: within half its last printed digit, and f32's
/// rounding.
fn assert_close(tb: f64, cell: &str, what: &str) {
    let want: f64 = cell.parse().expect("number");
    let decimals = cell.split('.').nth(1).map_or(0, str::len) as i32;
    let tol = 0.5 * 10f64.powi(-decimals) + 1e-6 * want.abs() + 1e-9;
    assert!(
        (tb - want).abs() <= tol,
        "{what}: TensorBoard {tb}, metrics.csv {cell}"
    );
}

#[test]
fn tensorboard_reads_every_metrics_csv_number_at_its_env_steps() {
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("run");
    let run_s = run.display().to_string();
    let mut args = vec!["train", "--actors", "0", "--out", &run_s];
    args.extend_from_slice(SMOKE);
    let r = ess(&args);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let got = load(&run.join("tb"));
    let scalars = &got["scalars"];
    let (head, rows) = csv(&run.join("metrics.csv"));
    assert_eq!(rows.len(), 2, "two iterations");
    let col = |name: &str| head.iter().position(|c| c == name).expect(name);
    let mut checked = 0;
    for row in &rows {
        let step: u64 = row[col("env_steps")].parse().expect("env_steps");
        for (name, cell) in head.iter().zip(row) {
            if name == "env_steps" || cell.is_empty() {
                continue;
            }
            let per_k = match name.as_str() {
                "prior" => Some("prior/p_c"),
                "normalized_reward_per_code" => Some("eval/normalized_reward_code"),
                _ => None,
            };
            if let Some(prefix) = per_k {
                for (k, p) in cell.split(';').enumerate() {
                    let tag = format!("{prefix}{k}");
                    let tb = at(scalars, &tag, step).unwrap_or_else(|| panic!("{tag} at {step}"));
                    assert_close(tb, p, &tag);
                    checked += 1;
                }
                continue;
            }
            let tag = tag_of(scalars, name).unwrap_or_else(|| panic!("no tag for column {name}"));
            let tb = at(scalars, &tag, step).unwrap_or_else(|| panic!("{tag} at step {step}"));
            assert_close(tb, cell, &format!("{tag} at step {step}"));
            checked += 1;
        }
    }
    assert!(checked > 40, "{checked} values checked");
    // The periodic (iteration 1) and final evaluations, per code, at their steps.
    let steps: Vec<u64> = rows
        .iter()
        .map(|r| r[col("env_steps")].parse().unwrap())
        .collect();
    let summary: Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap();
    let per_code = summary["eval"]["normalized_reward_per_code"]
        .as_array()
        .unwrap();
    for (k, want) in per_code.iter().enumerate() {
        let tag = format!("eval/normalized_reward_code{k}");
        assert!(
            at(scalars, &tag, steps[0]).is_some(),
            "{tag} at the periodic evaluation"
        );
        let last = at(scalars, &tag, steps[1]).expect("final evaluation");
        assert!(
            (last - want.as_f64().unwrap()).abs() < 1e-6,
            "{tag}: {last} vs {want}"
        );
    }
    // The config as text, the figures as images of their real size.
    let config = got["texts"]["config"][0].as_str().expect("config text");
    assert!(
        config.contains("[method]") && config.contains("traj2d"),
        "{config}"
    );
    for fig in ["trajectories", "curves"] {
        let img = &got["images"][fig][0];
        assert_eq!(img[0].as_u64(), Some(steps[1]), "{fig} at the last step");
        assert!(
            img[1].as_u64().unwrap() >= 200 && img[2].as_u64().unwrap() >= 200,
            "{img}"
        );
    }
}

#[test]
fn a_run_whose_tb_directory_cannot_be_made_trains_and_says_so_once() {
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("run");
    std::fs::create_dir_all(&run).unwrap();
    // A file where the directory would go: no event file can be created under it.
    std::fs::write(run.join("tb"), b"not a directory").unwrap();
    let run_s = run.display().to_string();
    let mut args = vec!["train", "--actors", "0", "--out", &run_s];
    args.extend_from_slice(SMOKE);
    let r = ess(&args);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{err}");
    assert_eq!(
        err.matches("TensorBoard event file not written").count(),
        1,
        "{err}"
    );
    assert!(err.contains(&run.join("tb").display().to_string()), "{err}");
    assert!(run.join("summary.json").exists() && run.join("metrics.csv").exists());
    assert_eq!(std::fs::read(run.join("tb")).unwrap(), b"not a directory");
}
