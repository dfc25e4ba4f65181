//! Control-plane figures for `bench/control.md`: submit-to-first-step latency and
//! WatchJob fan-out, against a real `ess serve` on 127.0.0.1.
//!
//! ```sh
//! cargo build -p ess-learner --bin ess            # or --release for both
//! cargo run -p ess-learner --example control_bench -- 5 1,10,100,1000
//! ```
//!
//! Arguments: latency repetitions (5), watcher counts (1,10,100,1000). The `ess` binary
//! is `$ESS_BIN`, else the one of this example's profile (`target/<profile>/ess`).
//!
//! - Latency: time from sending SubmitJob to its reply, to the job process's first
//!   progress line (`demonstrations`: process started, libtorch loaded), to its
//!   `training` phase (set-up done, the first rollout starts: "starts stepping"), and to
//!   the first iteration event on a WatchJob stream opened right after the reply. Each
//!   job is a tiny Traj2D run (2 iterations of 400 steps) with a 1-core budget.
//! - Fan-out: N watchers (100 per HTTP/2 connection) attach to a queued job of 200
//!   small iterations; events/s is every iteration event received by every watcher
//!   over the time from the first to the last delivery; the delivery lag of an event
//!   at a watcher is its arrival minus the earliest arrival of that iteration at any
//!   watcher (the fan-out spread; the server stamps no send time).

use anyhow::{Context, Result, bail};
use ess_proto::pb;
use ess_proto::pb::job_service_client::JobServiceClient;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use tonic::transport::Channel;

fn ess_bin() -> Result<PathBuf> {
    if let Ok(p) = std::env::var("ESS_BIN") {
        return Ok(PathBuf::from(p));
    }
    let exe = std::env::current_exe()?;
    let bin = exe
        .parent()
        .and_then(|d| d.parent())
        .context("target/<profile>")?
        .join("ess");
    if !bin.exists() {
        bail!(
            "{} not found: build it (cargo build -p ess-learner --bin ess) or set ESS_BIN",
            bin.display()
        );
    }
    Ok(bin)
}

fn spec(seed: u64, kv: &[(&str, String)]) -> pb::JobSpec {
    pb::JobSpec {
        seed: Some(seed),
        overrides: kv
            .iter()
            .map(|(k, v)| pb::Override {
                key: (*k).into(),
                value: v.clone(),
            })
            .collect(),
        ..Default::default()
    }
}

fn tiny(iterations: usize, rollout: usize) -> Vec<(&'static str, String)> {
    vec![
        ("run.iterations", iterations.to_string()),
        ("run.rollout_steps", rollout.to_string()),
        ("disc.steps", "1".into()),
        ("disc.batch", "32".into()),
        ("ppo.epochs", "1".into()),
        ("ppo.minibatch", rollout.to_string()),
        ("run.eval_episodes", "2".into()),
        ("run.eval_every", "100000".into()),
        ("run.reference_episodes", "2".into()),
        ("demos.majority_episodes", "20".into()),
        ("run.torch_threads", "1".into()),
    ]
}

fn stats(v: &mut [f64]) -> String {
    v.sort_by(f64::total_cmp);
    format!(
        "median {:.1} ms (min {:.1}, max {:.1})",
        v[v.len() / 2] * 1e3,
        v[0] * 1e3,
        v[v.len() - 1] * 1e3
    )
}

async fn latency(c: &mut JobServiceClient<Channel>, reps: usize) -> Result<()> {
    let (mut ack, mut first_line, mut stepping, mut first_it) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for r in 0..reps {
        let t0 = Instant::now();
        let j = c
            .submit_job(pb::SubmitJobRequest {
                spec: Some(spec(r as u64, &tiny(2, 400))),
            })
            .await?
            .into_inner();
        ack.push(t0.elapsed().as_secs_f64());
        let mut s = c
            .watch_job(pb::WatchJobRequest { id: j.id.clone() })
            .await?
            .into_inner();
        let (mut fl, mut st, mut fi) = (None, None, None);
        while let Some(ev) = s.message().await? {
            let t = t0.elapsed().as_secs_f64();
            let phase = ev.job.as_ref().map(|j| j.phase.as_str()).unwrap_or("");
            if fl.is_none() && !phase.is_empty() && phase != "starting" {
                fl = Some(t);
            }
            if st.is_none() && phase == "training" {
                st = Some(t);
            }
            if fi.is_none() && ev.metrics.is_some() {
                fi = Some(t);
            }
        }
        first_line.push(fl.context("no progress line seen")?);
        stepping.push(st.context("no training phase seen")?);
        first_it.push(fi.context("no iteration seen")?);
    }
    println!("## Submit to first step ({reps} jobs, one at a time)\n");
    println!("| from SubmitJob sent to | time |\n|---|---|");
    println!(
        "| SubmitJob reply (validated, queued, child spawned) | {} |",
        stats(&mut ack)
    );
    println!(
        "| child's first progress line (process up, libtorch loaded) | {} |",
        stats(&mut first_line)
    );
    println!(
        "| child starts stepping (`training` phase: demos + classifier + reference done) | {} |",
        stats(&mut stepping)
    );
    println!(
        "| first iteration event on WatchJob | {} |",
        stats(&mut first_it)
    );
    println!();
    Ok(())
}

async fn fanout(url: &str, c: &mut JobServiceClient<Channel>, n: usize, seed: u64) -> Result<()> {
    let blocker = c
        .submit_job(pb::SubmitJobRequest {
            spec: Some(spec(seed + 1000, &tiny(100_000, 100))),
        })
        .await?
        .into_inner();
    let n_it = 200u32;
    let job = c
        .submit_job(pb::SubmitJobRequest {
            spec: Some(spec(seed, &tiny(n_it as usize, 100))),
        })
        .await?
        .into_inner();
    let mut channels = Vec::new();
    for _ in 0..n.div_ceil(100) {
        channels.push(Channel::from_shared(url.to_string())?.connect().await?);
    }
    let t0 = Instant::now();
    let mut handles = Vec::new();
    for w in 0..n {
        let mut wc = JobServiceClient::new(channels[w / 100].clone());
        let mut s = wc
            .watch_job(pb::WatchJobRequest { id: job.id.clone() })
            .await?
            .into_inner();
        handles.push(tokio::spawn(async move {
            let mut arrivals = Vec::new();
            while let Ok(Some(ev)) = s.message().await {
                if let Some(m) = ev.metrics {
                    arrivals.push((m.iteration, t0.elapsed().as_secs_f64()));
                }
            }
            arrivals
        }));
    }
    c.stop_job(pb::StopJobRequest { id: blocker.id }).await?;
    let mut all = Vec::new();
    for h in handles {
        all.push(h.await?);
    }
    let complete = all.iter().filter(|a| a.len() == n_it as usize).count();
    let mut earliest = vec![f64::INFINITY; n_it as usize + 1];
    for a in &all {
        for &(i, t) in a {
            earliest[i as usize] = earliest[i as usize].min(t);
        }
    }
    let (mut first, mut last, mut events, mut max_lag, mut lags) =
        (f64::INFINITY, 0f64, 0usize, 0f64, Vec::new());
    for a in &all {
        for &(i, t) in a {
            first = first.min(t);
            last = last.max(t);
            events += 1;
            let lag = t - earliest[i as usize];
            max_lag = max_lag.max(lag);
            lags.push(lag);
        }
    }
    lags.sort_by(f64::total_cmp);
    let p99 = lags[(lags.len() * 99 / 100).min(lags.len() - 1)];
    let span = (last - first).max(1e-9);
    println!(
        "| {n} | {complete}/{n} | {events} | {:.0} | {:.0} | {:.1} | {:.1} |",
        f64::from(n_it - 1) / span,
        events as f64 / span,
        p99 * 1e3,
        max_lag * 1e3
    );
    Ok(())
}

#[tokio::main]
async fn main() -> Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let reps: usize = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(5);
    let ns: Vec<usize> = a
        .get(2)
        .map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect())
        .unwrap_or_else(|| vec![1, 10, 100, 1000]);
    let dir = std::env::temp_dir().join(format!("ess-control-bench-{}", std::process::id()));
    let mut server = Command::new(ess_bin()?)
        .args([
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--cores",
            "1",
            "--data-dir",
        ])
        .arg(&dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .context("starting ess serve")?;
    let mut line = String::new();
    BufReader::new(server.stdout.take().context("stdout")?).read_line(&mut line)?;
    let addr = line
        .trim()
        .strip_prefix("listening on ")
        .context("no address line")?;
    let url = format!("http://{addr}");
    let mut c = JobServiceClient::connect(url.clone()).await?;
    let r = async {
        latency(&mut c, reps).await?;
        println!("## WatchJob fan-out (one job of 200 iterations x 100 steps)\n");
        println!("| watchers | saw every iteration | events delivered | iterations/s as delivered | events/s delivered | p99 lag ms | max lag ms |");
        println!("|---|---|---|---|---|---|---|");
        for (k, &n) in ns.iter().enumerate() {
            fanout(&url, &mut c, n, 100 + k as u64).await?;
        }
        anyhow::Ok(())
    }
    .await;
    let _ = nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(server.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    );
    let _ = server.wait();
    tokio::time::sleep(Duration::from_millis(10)).await;
    let _ = std::fs::remove_dir_all(&dir);
    r
}
