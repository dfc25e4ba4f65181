//! `ess export RUN --onnx FILE`: the model loads in tract (a pure-Rust ONNX runtime,
//! not ours) and gives the actions of our own policy forward within 1e-5.

use ess_tests::{SMOKE, ess};
use tract_onnx::prelude::*;

#[test]
fn the_onnx_policy_gives_our_actions_in_tract() {
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

    let (w, cfg, _) = ess_learner::export::run_policy(std::path::Path::new(&run)).unwrap();
    let (od, k) = (w.obs_mean.len(), cfg.env.n_modes);
    let ad = w.log_std.len();
    let n = 64;
    let model = tract_onnx::onnx()
        .model_for_path(&model_path)
        .unwrap()
        .with_input_fact(0, f32::fact([n, od]).into())
        .unwrap()
        .with_input_fact(1, f32::fact([n, 1]).into())
        .unwrap()
        .with_input_fact(2, f32::fact([n, k]).into())
        .unwrap()
        .into_optimized()
        .unwrap()
        .into_runnable()
        .unwrap();
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
    let out = model
        .run(tvec!(
            tract_ndarray::Array2::from_shape_vec((n, od), obs.clone())
                .unwrap()
                .into_tensor()
                .into(),
            tract_ndarray::Array2::from_shape_vec((n, 1), eps.clone())
                .unwrap()
                .into_tensor()
                .into(),
            tract_ndarray::Array2::from_shape_vec((n, k), c.clone())
                .unwrap()
                .into_tensor()
                .into(),
        ))
        .unwrap();
    let got = out[0].to_plain_array_view::<f32>().unwrap();
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
            worst = worst.max((got[[row, j]] - a).abs());
        }
    }
    assert!(worst <= 1e-5, "largest difference {worst}");
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
