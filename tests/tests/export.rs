//! `ess export RUN --onnx FILE`: the model loads in onnxruntime (Microsoft's ONNX
//! runtime, run from Python as a deploying user would) and gives the actions of our own
//! policy forward within 1e-5. onnxruntime and numpy come from PyPI into
//! `.deps/pytest` (`scripts/bootstrap.sh --nextest`, which `make test` runs), or from
//! `$ESS_TEST_PYTHONPATH`; `ess` itself never calls Python.

use std::path::Path;

use ess_tests::{SMOKE, ess, pytest_path, python};
use serde_json::{Value, json};

/// Runs the model at `model` in onnxruntime on `inputs` (row-major f32 arrays with their
/// shapes, in the model's input order) and returns its first output, row-major.
const RUN_IN_ONNXRUNTIME: &str = r#"
import json, sys
import numpy as np
import onnxruntime as ort
model, feeds_path = sys.argv[1], sys.argv[2]
with open(feeds_path) as f:
    feeds = json.load(f)
s = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
names = [i.name for i in s.get_inputs()]
if len(names) != len(feeds):
    sys.exit(f"model has inputs {names}, test gave {len(feeds)}")
arrays = {n: np.asarray(x["data"], dtype=np.float32).reshape(x["shape"]) for n, x in zip(names, feeds)}
out = s.run(None, arrays)[0]
json.dump({"version": ort.__version__, "shape": list(out.shape), "data": out.astype(np.float64).ravel().tolist()}, sys.stdout)
"#;

fn onnxruntime_run(model: &Path, inputs: &[(&[f32], [usize; 2])], dir: &Path) -> (Vec<f32>, Value) {
    let feeds: Vec<Value> = inputs
        .iter()
        .map(|(data, shape)| json!({ "data": data, "shape": shape }))
        .collect();
    let feeds_path = dir.join("feeds.json");
    std::fs::write(&feeds_path, serde_json::to_vec(&feeds).unwrap()).unwrap();
    let pythonpath = pytest_path();
    let out = python(
        RUN_IN_ONNXRUNTIME,
        &[model.as_os_str(), feeds_path.as_os_str()],
    );
    assert!(
        out.status.success(),
        "onnxruntime (PYTHONPATH {}; `bash scripts/bootstrap.sh --nextest` installs it) failed: {}",
        pythonpath.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let data = v["data"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap() as f32)
        .collect();
    (data, v)
}

#[test]
fn the_onnx_policy_gives_our_actions_in_onnxruntime() {
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("run").display().to_string();
    let mut args = vec!["train", "--actors", "0", "--out", &run];
    args.extend_from_slice(SMOKE);
    let r = ess(&args);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let model_path = d.path().join("policy.onnx");
    let m = model_path.display().to_string();
    let r = ess(&["export", &run, "--onnx", &m]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));

    let (w, cfg, _) = ess_learner::export::run_policy(Path::new(&run)).unwrap();
    let (od, k) = (w.obs_mean.len(), cfg.env.n_modes);
    let ad = w.log_std.len();
    let n = 64;
    // Inputs spread over the data's range: obs around the normaliser, eps in [-1, 1].
    let mut x = 0x9e37_79b9u32;
    let mut rnd = || {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        (x as f32 / u32::MAX as f32) * 2.0 - 1.0
    };
    let obs: Vec<f32> = (0..n * od)
        .map(|i| w.obs_mean[i % od] + 2.0 * w.obs_std[i % od] * rnd())
        .collect();
    let eps: Vec<f32> = (0..n).map(|_| rnd()).collect();
    let mut c = vec![0.0f32; n * k];
    for row in 0..n {
        c[row * k + row % k] = 1.0;
    }
    let inputs = [(&obs[..], [n, od]), (&eps[..], [n, 1]), (&c[..], [n, k])];
    let (got, raw) = onnxruntime_run(&model_path, &inputs, d.path());
    assert_eq!(raw["shape"], json!([n, ad]), "{raw}");
    let mut actor = ess_actor::Actor::new(&w);
    let mut act = vec![0.0f32; ad];
    let mut worst = 0.0f32;
    for row in 0..n {
        actor.act_deterministic(
            &w,
            &obs[row * od..(row + 1) * od],
            eps[row],
            &c[row * k..(row + 1) * k],
            &mut act,
        );
        for (j, a) in act.iter().enumerate() {
            worst = worst.max((got[row * ad + j] - a).abs());
        }
    }
    assert!(
        worst <= 1e-5,
        "largest difference {worst} (onnxruntime {})",
        raw["version"]
    );
}

#[test]
fn exporting_something_that_is_not_a_run_is_one_line_exit_2() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("p.onnx").display().to_string();
    let r = ess(&["export", &d.path().display().to_string(), "--onnx", &out]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(
        err.trim().lines().count() == 1 && err.contains("no config.toml"),
        "{err}"
    );
    assert!(!d.path().join("p.onnx").exists());
}
