//! The control plane as a user drives it: a real `ess serve` on 127.0.0.1 (ephemeral
//! port, temporary data dir) and the `ess job` client or a gRPC client against it. Jobs
//! are tiny Traj2D runs (a few seconds of training).

use ess_proto::pb;
use ess_proto::pb::job_service_client::JobServiceClient;
use ess_tests::{children_of, ess_bin, is_running, start_serve, wait_gone};
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};
use tonic::Code;
use tonic::transport::Channel;

/// Overrides that make a Traj2D job take well under a second per iteration.
fn tiny(iterations: usize, eval_every: usize) -> Vec<(String, String)> {
    [
        ("run.iterations", iterations.to_string()),
        ("run.rollout_steps", "400".into()),
        ("disc.steps", "3".into()),
        ("disc.batch", "64".into()),
        ("ppo.epochs", "2".into()),
        ("ppo.minibatch", "200".into()),
        ("run.eval_episodes", "2".into()),
        ("run.eval_every", eval_every.to_string()),
        ("run.eval_episodes_periodic", "1".into()),
        ("run.reference_episodes", "2".into()),
        ("demos.majority_episodes", "20".into()),
        ("run.torch_threads", "1".into()),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect()
}

fn spec(seed: u64, overrides: &[(String, String)]) -> pb::JobSpec {
    pb::JobSpec {
        seed: Some(seed),
        overrides: overrides
            .iter()
            .map(|(k, v)| pb::Override {
                key: k.clone(),
                value: v.clone(),
            })
            .collect(),
        ..Default::default()
    }
}

/// `--set k=v` flags for the CLI.
fn set_flags(overrides: &[(String, String)]) -> Vec<String> {
    overrides
        .iter()
        .flat_map(|(k, v)| ["--set".to_string(), format!("{k}={v}")])
        .collect()
}

/// A running `ess serve`; stopped with SIGTERM when dropped.
struct Server {
    child: Child,
    addr: String,
    data: PathBuf,
    stderr_path: PathBuf,
}

impl Server {
    fn start(data: &Path, extra: &[&str]) -> Server {
        let stderr_path = data.with_extension("stderr");
        let mut args: Vec<&OsStr> = vec!["--data-dir".as_ref(), data.as_os_str()];
        args.extend(extra.iter().map(OsStr::new));
        let (child, addr) = start_serve(&args, &stderr_path);
        Server {
            child,
            addr,
            data: data.to_path_buf(),
            stderr_path,
        }
    }

    fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }

    async fn client(&self) -> JobServiceClient<Channel> {
        JobServiceClient::connect(self.url()).await.unwrap()
    }

    /// Runs `ess job --server URL args...`.
    fn job(&self, args: &[&str]) -> Output {
        Command::new(ess_bin())
            .args(["job", "--server", &self.url()])
            .args(args)
            .env("RUST_LOG", "warn")
            .env_remove("ESS_TOKEN_FILE")
            .output()
            .unwrap()
    }

    /// SIGTERM, then waits for the exit; returns its status.
    fn terminate(&mut self) -> std::process::ExitStatus {
        sigterm(self.pid());
        self.child.wait().unwrap()
    }

    fn stderr(&self) -> String {
        std::fs::read_to_string(&self.stderr_path).unwrap_or_default()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            sigterm(self.pid());
            let _ = self.child.wait();
        }
    }
}

fn sigterm(pid: u32) {
    let _ = nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(pid as i32),
        nix::sys::signal::Signal::SIGTERM,
    );
}

fn out(o: &Output) -> String {
    format!(
        "status {:?}\nstdout: {}\nstderr: {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn json(o: &Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", out(o));
    serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}: {}", out(o)))
}

fn state(j: &pb::Job) -> pb::JobState {
    pb::JobState::try_from(j.state).unwrap()
}

/// Watches `id` until its stream ends; returns the events.
async fn watch_all(c: &mut JobServiceClient<Channel>, id: &str) -> Vec<pb::JobEvent> {
    let mut s = c
        .watch_job(pb::WatchJobRequest { id: id.into() })
        .await
        .unwrap()
        .into_inner();
    let mut v = Vec::new();
    while let Some(ev) = s.message().await.unwrap() {
        v.push(ev);
    }
    v
}

/// Polls `id` until `pred` holds (or panics after `secs`).
async fn wait_for(
    c: &mut JobServiceClient<Channel>,
    id: &str,
    secs: f64,
    pred: impl Fn(&pb::Job) -> bool,
) -> pb::Job {
    let deadline = Instant::now() + Duration::from_secs_f64(secs);
    loop {
        let j = c
            .get_job(pb::GetJobRequest { id: id.into() })
            .await
            .unwrap()
            .into_inner();
        if pred(&j) {
            return j;
        }
        assert!(Instant::now() < deadline, "timed out waiting on {j:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// `metrics.csv` without its wall-time columns.
fn metrics_without_times(run_dir: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(run_dir.join("metrics.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let keep: Vec<usize> = header
        .iter()
        .enumerate()
        .filter(|(_, h)| !matches!(**h, "wall_s" | "rollout_s" | "disc_s" | "ppo_s"))
        .map(|(i, _)| i)
        .collect();
    assert!(keep.len() + 4 == header.len(), "{header:?}");
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            keep.iter().map(|&i| cells[i].to_string()).collect()
        })
        .collect()
}

fn summary(run_dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(run_dir.join("summary.json")).unwrap()).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_submitted_job_is_watched_to_completion_then_listed_and_got() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("data"), &[]);
    let mut args = vec![
        "submit".to_string(),
        "--json".into(),
        "--seed".into(),
        "3".into(),
    ];
    args.extend(set_flags(&tiny(3, 1)));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let j = json(&server.job(&args));
    let id = j["id"].as_str().unwrap().to_string();
    assert_eq!(j["iterations"], 3);
    assert!(
        matches!(j["state"].as_str(), Some("QUEUED" | "RUNNING")),
        "{j}"
    );

    // `watch --json`: one event per line, every iteration in order, the end state last.
    let o = server.job(&["watch", &id, "--json"]);
    assert!(o.status.success(), "{}", out(&o));
    let events: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let iterations: Vec<u64> = events
        .iter()
        .filter_map(|e| e["metrics"]["iteration"].as_u64())
        .collect();
    assert_eq!(iterations, [1, 2, 3], "{events:?}");
    let last = &events.last().unwrap()["job"];
    assert_eq!(last["state"], "SUCCEEDED", "{last}");

    // Human `watch` of the finished job: its state and result, exit 0.
    let o = server.job(&["watch", &id]);
    assert!(o.status.success(), "{}", out(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("SUCCEEDED"));

    let list = json(&server.job(&["list", "--json"]));
    assert_eq!(list.as_array().unwrap().len(), 1, "{list}");
    assert_eq!(list[0]["id"], id.as_str());
    let got = json(&server.job(&["get", &id, "--json"]));
    assert_eq!(got["state"], "SUCCEEDED");
    assert_eq!(got["iteration"], 3);
    assert_eq!(got["spec"]["seed"], 3);
    // The result is the run's summary.json.
    let run_dir = PathBuf::from(got["run_dir"].as_str().unwrap());
    assert!(run_dir.starts_with(&server.data), "{run_dir:?}");
    let s = summary(&run_dir);
    assert_eq!(got["result"]["nmi"], s["nmi"]);
    assert_eq!(got["result"]["env_steps"], 1200);
    assert_eq!(s["seed"], 3);
    // Filters and errors.
    let none = json(&server.job(&["list", "--json", "--state", "running"]));
    assert_eq!(none.as_array().unwrap().len(), 0);
    let o = server.job(&["get", "job-999"]);
    assert_eq!(o.status.code(), Some(2), "{}", out(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("NotFound"));
    let o = server.job(&["resume", &id]);
    assert_eq!(o.status.code(), Some(2), "{}", out(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("FailedPrecondition"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stopped_job_resumes_to_the_result_of_an_uninterrupted_one() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("data"), &["--cores", "2"]);
    let mut c = server.client().await;
    // The single-process path: its resume is bit-identical (actor processes restart
    // their episodes on resume).
    let mut o = tiny(30, 1000);
    o.push(("run.transport".into(), "\"threads\"".into()));
    o.push(("run.actors".into(), "1".into()));
    let submit = |c: &mut JobServiceClient<Channel>| {
        let s = spec(11, &o);
        let mut c = c.clone();
        async move {
            c.submit_job(pb::SubmitJobRequest { spec: Some(s) })
                .await
                .unwrap()
                .into_inner()
        }
    };
    let stopped = submit(&mut c).await;
    // Stop once the first iteration is in.
    let mut s = c
        .watch_job(pb::WatchJobRequest {
            id: stopped.id.clone(),
        })
        .await
        .unwrap()
        .into_inner();
    while let Some(ev) = s.message().await.unwrap() {
        if ev.metrics.is_some() {
            break;
        }
    }
    let j = c
        .stop_job(pb::StopJobRequest {
            id: stopped.id.clone(),
        })
        .await
        .unwrap()
        .into_inner();
    assert!(
        matches!(state(&j), pb::JobState::Stopping | pb::JobState::Stopped),
        "{j:?}"
    );
    let j = wait_for(&mut c, &stopped.id, 120.0, |j| {
        state(j) == pb::JobState::Stopped
    })
    .await;
    assert!(
        j.iteration < 30,
        "the stop came too late to test resume: {j:?}"
    );
    let stopped_at = j.iteration;
    let run_dir = PathBuf::from(&j.run_dir);
    assert_eq!(summary(&run_dir)["interrupted"], true);

    // Resume and watch it to the end: it continues after the stop, not from scratch.
    let r = c
        .resume_job(pb::ResumeJobRequest {
            id: stopped.id.clone(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.resumes, 1);
    let events = watch_all(&mut c, &stopped.id).await;
    let its: Vec<u32> = events
        .iter()
        .filter_map(|e| e.metrics.as_ref().map(|m| m.iteration))
        .collect();
    let end = events.last().unwrap().job.clone().unwrap();
    assert_eq!(state(&end), pb::JobState::Succeeded, "{end:?}");
    assert_eq!(
        its.first().copied(),
        Some(stopped_at + 1),
        "the resumed job should continue after iteration {stopped_at}: {its:?}"
    );

    // The same spec uninterrupted.
    let whole = submit(&mut c).await;
    let events = watch_all(&mut c, &whole.id).await;
    let whole = events.last().unwrap().job.clone().unwrap();
    assert_eq!(state(&whole), pb::JobState::Succeeded, "{whole:?}");
    let whole_dir = PathBuf::from(&whole.run_dir);
    let (a, b) = (summary(&run_dir), summary(&whole_dir));
    for key in ["nmi", "ent", "normalized_reward", "env_steps"] {
        assert_eq!(a[key], b[key], "summary.json {key}");
    }
    assert_eq!(a["interrupted"], false);
    assert_eq!(
        metrics_without_times(&run_dir),
        metrics_without_times(&whole_dir)
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn calls_without_the_right_token_are_unauthenticated() {
    let dir = tempfile::tempdir().unwrap();
    let tok = dir.path().join("token");
    std::fs::write(&tok, "correct-horse\n").unwrap();
    let server = Server::start(
        &dir.path().join("data"),
        &["--token-file", tok.to_str().unwrap()],
    );
    let channel = Channel::from_shared(server.url())
        .unwrap()
        .connect()
        .await
        .unwrap();
    let call = |auth: Option<&'static str>| {
        let channel = channel.clone();
        async move {
            let mut c = JobServiceClient::new(channel);
            let mut req = tonic::Request::new(pb::ListJobsRequest::default());
            if let Some(a) = auth {
                req.metadata_mut()
                    .insert("authorization", a.parse().unwrap());
            }
            c.list_jobs(req).await
        }
    };
    assert_eq!(call(None).await.unwrap_err().code(), Code::Unauthenticated);
    assert_eq!(
        call(Some("Bearer wrong-horse")).await.unwrap_err().code(),
        Code::Unauthenticated
    );
    assert_eq!(
        call(Some("correct-horse")).await.unwrap_err().code(),
        Code::Unauthenticated
    );
    assert!(call(Some("Bearer correct-horse")).await.is_ok());
    // Every JobService method is behind the check, streams included.
    let mut c = JobServiceClient::new(channel.clone());
    let e = c
        .watch_job(pb::WatchJobRequest { id: "job-1".into() })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated);
    // Health stays open.
    let mut h = tonic_health::pb::health_client::HealthClient::new(channel.clone());
    let r = h
        .check(tonic_health::pb::HealthCheckRequest {
            service: "ess.v1.JobService".into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        r.status(),
        tonic_health::pb::health_check_response::ServingStatus::Serving
    );
    // So does reflection (what grpcurl and other generic clients discover the API
    // with): it lists JobService and serves the file declaring it.
    assert_reflection_serves_the_job_service(channel.clone()).await;
    assert_v1alpha_reflection_lists_the_job_service(channel.clone()).await;
    // The CLI: the token file works; a wrong one is an input error naming the code.
    let bad = dir.path().join("bad");
    std::fs::write(&bad, "nope").unwrap();
    let o = server.job(&["list", "--token-file", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", out(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("Unauthenticated"));
    let o = server.job(&["list", "--token-file", tok.to_str().unwrap()]);
    assert!(o.status.success(), "{}", out(&o));
}

#[test]
fn serve_refuses_an_empty_token_file_and_a_plain_text_remote_listener() {
    let dir = tempfile::tempdir().unwrap();
    let tok = dir.path().join("token");
    std::fs::write(&tok, "  \n").unwrap();
    let o = Command::new(ess_bin())
        .args(["serve", "--listen", "127.0.0.1:0", "--token-file"])
        .arg(&tok)
        .arg("--data-dir")
        .arg(dir.path().join("d"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", out(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("token") && err.contains("empty"), "{err}");
    let o = Command::new(ess_bin())
        .args(["serve", "--listen", "0.0.0.0:0", "--data-dir"])
        .arg(dir.path().join("d"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", out(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("--tls-cert"),
        "{}",
        out(&o)
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_specs_are_rejected_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("data"), &[]);
    let mut c = server.client().await;
    let ok = ("run.iterations".to_string(), "2".to_string());
    let cases: Vec<(pb::JobSpec, &str, &str)> = vec![
        (
            pb::JobSpec {
                preset: "gial".into(),
                ..Default::default()
            },
            "spec.preset",
            "gial",
        ),
        (
            spec(1, &[ok.clone(), ("ppo.lrr".into(), "1".into())]),
            "spec.overrides[1].key",
            "ppo.lrr",
        ),
        (
            spec(
                1,
                &[
                    ok.clone(),
                    ok.clone(),
                    ("run.iterations".into(), "lots".into()),
                ],
            ),
            "spec.overrides[2].value",
            "run.iterations",
        ),
        (
            spec(1, &[("demos.label_ratio".into(), "1.5".into())]),
            "spec.overrides[0].value",
            "demos.label_ratio",
        ),
        (
            pb::JobSpec {
                env: "mars".into(),
                ..Default::default()
            },
            "spec.env",
            "mars",
        ),
        (
            pb::JobSpec {
                config_toml: "[run]\nseeds = 3\n".into(),
                ..Default::default()
            },
            "spec.config_toml",
            "run.seeds",
        ),
    ];
    for (s, field, names) in cases {
        let e = c
            .submit_job(pb::SubmitJobRequest { spec: Some(s) })
            .await
            .unwrap_err();
        assert_eq!(e.code(), Code::InvalidArgument, "{field}: {e:?}");
        assert!(
            e.message().starts_with(&format!("{field}: ")) && e.message().contains(names),
            "{field}: {}",
            e.message()
        );
    }
    // The CLI shows the same message and exits 2; nothing was queued.
    let o = server.job(&["submit", "--env", "mars"]);
    assert_eq!(o.status.code(), Some(2), "{}", out(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("spec.env: "));
    let jobs = c
        .list_jobs(pb::ListJobsRequest::default())
        .await
        .unwrap()
        .into_inner()
        .jobs;
    assert!(jobs.is_empty(), "{jobs:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hundred_watchers_each_receive_every_iteration() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("data"), &["--cores", "1"]);
    let mut c = server.client().await;
    // A long job holds the only core, so the watched job waits in the queue while the
    // watchers attach. (1000 tiny iterations were done in ~3 s on the fused backend in
    // a release build, before the stop came: it must outlast the attaching.)
    let blocker = c
        .submit_job(pb::SubmitJobRequest {
            spec: Some(spec(1, &tiny(100_000, 1000))),
        })
        .await
        .unwrap()
        .into_inner();
    let n_it = 8;
    let watched = c
        .submit_job(pb::SubmitJobRequest {
            spec: Some(spec(2, &tiny(n_it, 1000))),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(state(&watched), pb::JobState::Queued, "{watched:?}");
    let mut streams = Vec::new();
    for _ in 0..100 {
        let mut c = c.clone();
        let mut s = c
            .watch_job(pb::WatchJobRequest {
                id: watched.id.clone(),
            })
            .await
            .unwrap()
            .into_inner();
        let first = s.message().await.unwrap().unwrap();
        assert_eq!(state(first.job.as_ref().unwrap()), pb::JobState::Queued);
        streams.push(tokio::spawn(async move {
            let mut its = Vec::new();
            let mut last = None;
            while let Some(ev) = s.message().await.unwrap() {
                if let Some(m) = ev.metrics {
                    its.push(m.iteration);
                }
                last = ev.job;
            }
            (its, last.unwrap())
        }));
    }
    c.stop_job(pb::StopJobRequest {
        id: blocker.id.clone(),
    })
    .await
    .unwrap();
    let want: Vec<u32> = (1..=n_it as u32).collect();
    for h in streams {
        let (its, last) = h.await.unwrap();
        assert_eq!(its, want);
        assert_eq!(state(&last), pb::JobState::Succeeded, "{last:?}");
    }
    let b = wait_for(&mut c, &blocker.id, 60.0, |j| {
        state(j) == pb::JobState::Stopped
    })
    .await;
    assert!(b.iteration < 100_000);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_server_stops_its_jobs_on_sigterm_and_leaves_no_process_behind() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let mut server = Server::start(&data, &["--cores", "1"]);
    let mut c = server.client().await;
    let long = spec(5, &tiny(1000, 1000));
    let running = c
        .submit_job(pb::SubmitJobRequest {
            spec: Some(long.clone()),
        })
        .await
        .unwrap()
        .into_inner();
    let queued = c
        .submit_job(pb::SubmitJobRequest {
            spec: Some(long.clone()),
        })
        .await
        .unwrap()
        .into_inner();
    wait_for(&mut c, &running.id, 60.0, |j| j.iteration >= 1).await;
    let kids = children_of(server.pid());
    assert_eq!(kids.len(), 1, "one job process: {kids:?}");
    let status = server.terminate();
    assert!(status.success(), "{status:?}: {}", server.stderr());
    assert_eq!(wait_gone(&kids, 30.0), Vec::<u32>::new());
    let rec: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(data.join("jobs").join(&running.id).join("job.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(rec["state"], "stopped", "{rec}");
    drop(c);

    // A new server on the same data dir lists both jobs: the stopped one STOPPED, the
    // queued one queued again (and started, as the core is free).
    let mut server = Server::start(&data, &["--cores", "1"]);
    let mut c = server.client().await;
    let jobs = c
        .list_jobs(pb::ListJobsRequest::default())
        .await
        .unwrap()
        .into_inner()
        .jobs;
    assert_eq!(jobs.len(), 2, "{jobs:?}");
    assert_eq!(jobs[0].id, running.id);
    assert_eq!(state(&jobs[0]), pb::JobState::Stopped);
    assert_eq!(jobs[1].id, queued.id);
    assert!(matches!(
        state(&jobs[1]),
        pb::JobState::Queued | pb::JobState::Running
    ));
    // Killed hard while the job runs: the next server marks the job FAILED (resumable).
    wait_for(&mut c, &queued.id, 60.0, |j| j.iteration >= 1).await;
    let kids = children_of(server.pid());
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(server.pid() as i32),
        nix::sys::signal::Signal::SIGKILL,
    )
    .unwrap();
    let _ = server.child.wait();
    // Its job finds the progress pipe closed and stops gracefully by itself.
    let left = wait_gone(&kids, 60.0);
    for &k in &left {
        sigterm(k);
    }
    assert_eq!(left, Vec::<u32>::new(), "the orphaned job kept running");
    let run_dir = data.join("jobs").join(&queued.id);
    assert_eq!(summary(&run_dir)["interrupted"], true);
    assert!(
        std::fs::read_dir(run_dir.join("checkpoints"))
            .unwrap()
            .any(|e| e
                .unwrap()
                .file_name()
                .to_string_lossy()
                .starts_with("iter-")),
        "no checkpoint in {}",
        run_dir.display()
    );
    drop(c);
    let server = Server::start(&data, &["--cores", "1"]);
    let mut c = server.client().await;
    let j = c
        .get_job(pb::GetJobRequest {
            id: queued.id.clone(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(state(&j), pb::JobState::Failed, "{j:?}");
    assert!(j.error.contains("server exited"), "{}", j.error);
    assert!(children_of(server.pid()).is_empty());
    assert!(is_running(server.pid()));
}

/// `grpc.reflection.v1alpha`, which older tools still ask for, lists the services too.
async fn assert_v1alpha_reflection_lists_the_job_service(channel: Channel) {
    use tonic_reflection::pb::v1alpha::ServerReflectionRequest;
    use tonic_reflection::pb::v1alpha::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1alpha::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1alpha::server_reflection_response::MessageResponse;
    let req = ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut stream = ServerReflectionClient::new(channel)
        .server_reflection_info(tokio_stream::iter(vec![req]))
        .await
        .expect("v1alpha reflection call")
        .into_inner();
    let answer = stream.message().await.expect("v1alpha answer");
    match answer.and_then(|a| a.message_response) {
        Some(MessageResponse::ListServicesResponse(l)) => {
            let names: Vec<&str> = l.service.iter().map(|s| s.name.as_str()).collect();
            assert!(names.contains(&"ess.v1.JobService"), "{names:?}");
        }
        other => panic!("v1alpha list_services answered {other:?}"),
    }
}

/// One reflection stream: `list_services` names `ess.v1.JobService`, and
/// `file_containing_symbol` answers with the descriptor of `ess/v1/jobs.proto`.
async fn assert_reflection_serves_the_job_service(channel: Channel) {
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;
    use tonic_reflection::pb::v1::{ServerReflectionRequest, ServerReflectionResponse};
    let req = |m: MessageRequest| ServerReflectionRequest {
        host: String::new(),
        message_request: Some(m),
    };
    let requests = vec![
        req(MessageRequest::ListServices(String::new())),
        req(MessageRequest::FileContainingSymbol(
            "ess.v1.JobService".into(),
        )),
    ];
    let mut c = ServerReflectionClient::new(channel);
    let mut stream = c
        .server_reflection_info(tokio_stream::iter(requests))
        .await
        .expect("reflection call")
        .into_inner();
    let mut answers: Vec<ServerReflectionResponse> = Vec::new();
    while let Some(r) = stream.message().await.expect("reflection answer") {
        answers.push(r);
    }
    assert_eq!(answers.len(), 2, "{answers:?}");
    match &answers[0].message_response {
        Some(MessageResponse::ListServicesResponse(l)) => {
            let names: Vec<&str> = l.service.iter().map(|s| s.name.as_str()).collect();
            assert!(names.contains(&"ess.v1.JobService"), "{names:?}");
        }
        other => panic!("list_services answered {other:?}"),
    }
    match &answers[1].message_response {
        Some(MessageResponse::FileDescriptorResponse(f)) => {
            let files: Vec<prost_types::FileDescriptorProto> = f
                .file_descriptor_proto
                .iter()
                .map(|b| prost::Message::decode(b.as_slice()).expect("a FileDescriptorProto"))
                .collect();
            let jobs = files
                .iter()
                .find(|f| f.name() == "ess/v1/jobs.proto")
                .unwrap_or_else(|| {
                    panic!(
                        "no ess/v1/jobs.proto in {:?}",
                        files.iter().map(|f| f.name()).collect::<Vec<_>>()
                    )
                });
            let svc: Vec<&str> = jobs.service.iter().map(|s| s.name()).collect();
            assert_eq!(svc, ["JobService"]);
            let methods: Vec<&str> = jobs.service[0].method.iter().map(|m| m.name()).collect();
            for m in ["SubmitJob", "WatchJob", "StopJob", "ResumeJob"] {
                assert!(methods.contains(&m), "{m} missing from {methods:?}");
            }
        }
        other => panic!("file_containing_symbol answered {other:?}"),
    }
}

/// Hand-found: `ess train --actors 0` worked but `ess job submit --set run.actors=0` was
/// refused ("needs run.transport"); 0 now means one actor thread wherever it is set.
/// Also hand-found: the server's log, redirected to a file, carried ANSI colour codes.
#[test]
fn run_actors_0_is_accepted_by_job_submit_and_a_log_file_has_no_colour_codes() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("data"), &[]);
    let mut args = vec!["submit".to_string(), "--json".into(), "--watch".into()];
    args.extend(set_flags(&tiny(2, 0)));
    args.extend(["--set".to_string(), "run.actors=0".into()]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = server.job(&args);
    assert!(o.status.success(), "{}", out(&o));
    let last: serde_json::Value = String::from_utf8_lossy(&o.stdout)
        .lines()
        .last()
        .map(|l| serde_json::from_str(l).unwrap())
        .unwrap();
    assert_eq!(last["job"]["state"], "SUCCEEDED", "{last}");
    let run_dir = PathBuf::from(last["job"]["run_dir"].as_str().unwrap());
    let config = std::fs::read_to_string(run_dir.join("config.toml")).unwrap();
    assert!(config.contains("transport = \"threads\""), "{config}");
    let log = server.stderr();
    assert!(
        log.contains("INFO"),
        "the server logged nothing at info: {log}"
    );
    assert!(
        !log.contains('\u{1b}'),
        "escape codes in a log file: {log:?}"
    );
}

/// Hand-found: an empty `ESS_TOKEN_FILE` was read as the path "" (exit 2); it now counts
/// as unset, as an empty `ESS_SERVER` does.
#[test]
fn an_empty_token_file_variable_counts_as_unset() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("data"), &[]);
    let o = Command::new(ess_bin())
        .args(["job", "--server", &server.url(), "list", "--json"])
        .env("ESS_TOKEN_FILE", "")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", out(&o));
    assert_eq!(json(&o), serde_json::json!([]));
}
