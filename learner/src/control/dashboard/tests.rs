use super::*;

#[test]
fn metrics_json_gives_each_drawn_column_with_nulls_where_empty() {
    let csv = "iteration,env_steps,nmi,reward_mean\n1,400,,0.5\n2,800,0.9,0.25\n";
    let v = metrics_json(csv);
    assert_eq!(v["env_steps"], json!([400.0, 800.0]));
    assert_eq!(v["nmi"], json!([null, 0.9]));
    assert_eq!(v["reward_mean"], json!([0.5, 0.25]));
    // A column the file lacks is all null; an empty file has no points.
    assert_eq!(v["disc_bce"], json!([null, null]));
    assert_eq!(metrics_json("")["env_steps"], json!([]));
}

#[test]
fn a_submitted_spec_is_read_field_by_field_and_bad_fields_are_named() {
    let s = spec_from_json(
        r#"{"preset": "gail", "env": "reacher", "seed": 3, "overrides": [["run.iterations", "5"]]}"#,
    )
    .expect("spec");
    assert_eq!(
        (s.preset.as_str(), s.env.as_str(), s.seed),
        ("gail", "reacher", Some(3))
    );
    assert_eq!(s.overrides[0].key, "run.iterations");
    for (body, names) in [
        ("[1]", "expected a JSON object"),
        ("{", "not JSON"),
        (r#"{"seed": -1}"#, "seed"),
        (r#"{"seed": "x"}"#, "seed"),
        (r#"{"preset": 5}"#, "preset"),
        (r#"{"overrides": [["a"]]}"#, "overrides[0]"),
        (r#"{"overrides": "a=b"}"#, "overrides"),
        (r#"{"sed": 1}"#, "sed: unknown field"),
    ] {
        let e = spec_from_json(body).expect_err(body);
        assert!(e.contains(names), "{body}: {e}");
    }
}

#[test]
fn form_values_are_url_decoded() {
    assert_eq!(
        form_value("a=1&token=s3%2Bc+r", "token").as_deref(),
        Some("s3+c r")
    );
    assert_eq!(form_value("a=1", "token"), None);
}

#[test]
fn a_running_job_reports_progress_steps_per_second_and_eta() {
    let j = pb::Job {
        id: "j1".into(),
        state: pb::JobState::Running as i32,
        iteration: 25,
        iterations: 100,
        env_steps: 50_000,
        started_unix_ms: 1_000_000,
        ..Default::default()
    };
    let v = job_json(&j, 1_010_000);
    assert_eq!(v["state"], "running");
    assert_eq!(v["progress"], 0.25);
    assert_eq!(v["steps_per_s"], 5000.0);
    assert_eq!(v["eta_s"], 30.0);
}

#[test]
fn the_session_cookie_is_found_among_others() {
    let mut h = HeaderMap::new();
    h.insert(header::COOKIE, "a=b; ess_session=abc; c=d".parse().unwrap());
    assert_eq!(session_cookie(&h), Some("abc"));
}
