//! Actor hosts on other machines (`ess actor-host`, `[remote]`), each "machine" a network
//! namespace the test makes (a veth pair, its own address; removed afterwards), with
//! certificates made by `openssl`: a run with one local actor and one actor on each of
//! two hosts trains to the same numbers as three local actors; a host whose link is
//! cut mid-run is dropped with a warning and the run finishes on the others; a host may
//! join mid-run; a host whose certificate another CA signed is refused (these need root:
//! network namespaces). A host without `--once` serves one run after another until
//! Ctrl-C (on this machine's loopback, no root).

use ess_tests::pki::Pki;
use ess_tests::{SMOKE, actor_bin, ess, ess_bin};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

fn ip(args: &[&str]) {
    let o = Command::new("ip").args(args).output().expect("running ip");
    assert!(
        o.status.success(),
        "ip {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// A network namespace joined to this one by a veth pair: `10.S.I.1` here, `10.S.I.2`
/// in the namespace.
struct Netns {
    name: String,
    link: String,
    learner_ip: String,
}

impl Netns {
    fn new(i: u32) -> Netns {
        let tag = std::process::id() % 10_000;
        let (name, link, peer) = (
            format!("ess{tag}n{i}"),
            format!("ess{tag}a{i}"),
            format!("ess{tag}b{i}"),
        );
        let subnet = format!("10.{}.{i}", 20 + tag % 200);
        let me = Netns {
            name,
            link,
            learner_ip: format!("{subnet}.1"),
        };
        ip(&["netns", "add", &me.name]);
        ip(&[
            "link", "add", &me.link, "type", "veth", "peer", "name", &peer,
        ]);
        ip(&["link", "set", &peer, "netns", &me.name]);
        ip(&["addr", "add", &format!("{subnet}.1/24"), "dev", &me.link]);
        ip(&["link", "set", &me.link, "up"]);
        let inside = |args: &[&str]| {
            let mut a = vec!["netns", "exec", &me.name, "ip"];
            a.extend_from_slice(args);
            ip(&a);
        };
        inside(&["addr", "add", &format!("{subnet}.2/24"), "dev", &peer]);
        inside(&["link", "set", &peer, "up"]);
        inside(&["link", "set", "lo", "up"]);
        me
    }

    /// Cuts the link: the namespace's host can no longer reach the learner.
    fn cut(&self) {
        ip(&["link", "set", &self.link, "down"]);
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        let _ = Command::new("ip")
            .args(["link", "del", &self.link])
            .output();
        let _ = Command::new("ip")
            .args(["netns", "del", &self.name])
            .output();
    }
}

/// `ess actor-host --once` named `name` with one actor, in `ns` (or here), dialling
/// `learner` with `cert` (under `pki`); a host whose certificate is refused gives up
/// after 3 s.
fn actor_host(ns: Option<&Netns>, learner: &str, name: &str, pki: &Pki, cert: &str) -> Child {
    host_command(ns, learner, name, pki, cert)
        .arg("--once")
        .spawn()
        .expect("starting ess actor-host")
}

/// The `ess actor-host` command of [`actor_host`], without `--once`.
fn host_command(ns: Option<&Netns>, learner: &str, name: &str, pki: &Pki, cert: &str) -> Command {
    let connect = if cert == "stranger" { "3" } else { "20" };
    let mut cmd = match ns {
        Some(ns) => {
            let mut c = Command::new("ip");
            c.args(["netns", "exec", &ns.name]).arg(ess_bin());
            c
        }
        None => Command::new(ess_bin()),
    };
    cmd.args([
        "actor-host",
        "--learner",
        learner,
        "--name",
        name,
        "--actors",
        "1",
    ])
    .arg("--tls-ca")
    .arg(pki.path("ca.pem"))
    .arg("--tls-cert")
    .arg(pki.path(&format!("{cert}.pem")))
    .arg("--tls-key")
    .arg(pki.path(&format!("{cert}.key")))
    .args(["--connect-s", connect, "--timeout-s", "1"])
    .env("ESS_ACTOR_BIN", actor_bin())
    .env("RUST_LOG", "info")
    .stdout(Stdio::null())
    .stderr(Stdio::piped());
    cmd
}

fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("0.0.0.0:0").unwrap();
    l.local_addr().unwrap().port()
}

/// The learner's `[remote]` section: listening on every address, waiting for `hosts`.
fn remote_config(dir: &Path, port: u16, hosts: &[&str], pki: &Pki) -> PathBuf {
    let path = dir.join(format!("remote-{port}.toml"));
    let p = |f: &str| pki.path(f).display().to_string();
    std::fs::write(
        &path,
        format!(
            "[remote]\nlisten = \"tls/0.0.0.0:{port}\"\nhosts = {hosts:?}\nwait_s = 60\n\
             timeout_s = 1\ntls_ca = {:?}\ntls_cert = {:?}\ntls_key = {:?}\n",
            p("ca.pem"),
            p("server.pem"),
            p("server.key")
        ),
    )
    .unwrap();
    path
}

/// A learner config on a free port waiting for hosts `ha` and `hb`, and those hosts
/// (one actor each) started in namespaces `ns[0]` and `ns[1]`.
fn two_hosts(dir: &Path, ns: [&Netns; 2], pki: &Pki) -> (u16, PathBuf, [Child; 2]) {
    let port = free_port();
    let cfg = remote_config(dir, port, &["ha", "hb"], pki);
    let host = |n: &Netns, name: &str| {
        let learner = format!("tls/{}:{port}", n.learner_ip);
        actor_host(Some(n), &learner, name, pki, "client")
    };
    (port, cfg, [host(ns[0], "ha"), host(ns[1], "hb")])
}

fn train_args<'a>(out: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec!["train", "--seed", "3", "--out", out.to_str().unwrap()];
    args.extend_from_slice(SMOKE);
    args.extend_from_slice(&["--set", "run.reference_episodes=2"]);
    args.extend_from_slice(&["--set", "run.actor_timeout_s=120"]);
    args.extend_from_slice(extra);
    args
}

fn text(o: &Output) -> String {
    format!(
        "status {:?}\nstderr: {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// `metrics.csv` without its timing columns.
fn metrics(dir: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join("metrics.csv")).expect("metrics.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    lines
        .map(|l| {
            l.split(',')
                .zip(&header)
                .filter(|(_, h)| !h.ends_with("_s"))
                .map(|(f, _)| f)
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect()
}

fn summary(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

/// Waits for a host to end and returns its stderr.
fn host_log(mut h: Child, secs: u64) -> (Option<i32>, String) {
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(secs) {
        if let Ok(Some(_)) = h.try_wait() {
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let _ = h.kill();
    let o = h.wait_with_output().unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .any(|l| l.starts_with("Uid:") && l.split_whitespace().nth(1) == Some("0"))
}

#[test]
fn hosts_in_other_namespaces_train_like_local_actors_survive_a_cut_and_refuse_strangers() {
    if !is_root() {
        eprintln!("skipped: network namespaces need root");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (Netns::new(1), Netns::new(2));
    let pki = Pki::for_server_ips(&[&a.learner_ip, &b.learner_ip]);

    // Three local actors: the reference.
    let local = tmp.path().join("local");
    let o = ess(&train_args(&local, &["--actors", "3"]));
    assert!(o.status.success(), "local run: {}", text(&o));

    // One local actor, one on each host.
    let (_, cfg, hosts) = two_hosts(tmp.path(), [&a, &b], &pki);
    let remote = tmp.path().join("remote");
    let o = ess(&train_args(
        &remote,
        &["--actors", "1", "--config", cfg.to_str().unwrap()],
    ));
    let logs: Vec<_> = hosts.into_iter().map(|h| host_log(h, 10)).collect();
    assert!(
        o.status.success(),
        "remote run: {}\nhosts: {logs:?}",
        text(&o)
    );
    for (code, log) in &logs {
        assert_eq!(
            *code,
            Some(0),
            "a host ends with the run: {log}\nlearner: {}",
            text(&o)
        );
    }
    for key in ["nmi", "ent", "normalized_reward", "env_steps"] {
        assert_eq!(
            summary(&local)[key],
            summary(&remote)[key],
            "summary `{key}`"
        );
    }
    assert_eq!(
        metrics(&local),
        metrics(&remote),
        "same rollouts, same training"
    );

    // A cut mid-run, and a stranger.
    let (port, cfg, hosts) = two_hosts(tmp.path(), [&a, &b], &pki);
    let cut = tmp.path().join("cut");
    let mut args = train_args(&cut, &["--actors", "1", "--config", cfg.to_str().unwrap()]);
    // Long enough (~10 ms an iteration) that the cut and a late join fall well inside
    // the run.
    args.extend_from_slice(&[
        "--set",
        "run.iterations=500",
        "--set",
        "run.eval_every=1000",
    ]);
    let learner = Command::new(ess_bin())
        .args(&args)
        .env("RUST_LOG", "warn,ess_learner::remote=info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let rows = || std::fs::read_to_string(cut.join("metrics.csv")).map_or(0, |t| t.lines().count());
    let t0 = Instant::now();
    while rows() < 3 && t0.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(rows() >= 3, "the run reached iteration 2");
    let stranger = actor_host(
        None,
        &format!("tls/127.0.0.1:{port}"),
        "hc",
        &pki,
        "stranger",
    );
    a.cut();
    let late = actor_host(None, &format!("tls/127.0.0.1:{port}"), "hd", &pki, "client");
    let o = learner.wait_with_output().unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    let host_logs: Vec<_> = hosts
        .into_iter()
        .chain([late])
        .map(|h| host_log(h, 10))
        .collect();
    assert!(o.status.success(), "cut run: {log}\nhosts: {host_logs:?}");
    assert_eq!(summary(&cut)["iterations"], 500, "{log}");
    assert!(
        log.contains("actor host joined host=hd"),
        "a host joins mid-run: {log}"
    );
    assert_eq!(
        host_logs[2].0,
        Some(0),
        "the late host ends with the run: {host_logs:?}"
    );
    assert!(
        log.contains("actor host lost") && log.contains("host=ha"),
        "a warning names the lost host: {log}"
    );
    assert!(!log.contains("host=hb: actor host lost"), "{log}");
    assert!(
        !log.contains("host=hc") && !log.contains("host: hc"),
        "{log}"
    );
    let (code, slog) = host_log(stranger, 20);
    assert_ne!(code, Some(0), "the stranger is refused: {slog}");
    assert!(slog.contains("reaching the learner"), "{slog}");
}

#[test]
fn a_host_serves_one_run_after_another_until_ctrl_c() {
    let tmp = tempfile::tempdir().unwrap();
    let pki = Pki::new();
    let port = free_port();
    let cfg = remote_config(tmp.path(), port, &["hs"], &pki);
    let learner = format!("tls/127.0.0.1:{port}");
    let mut host = host_command(None, &learner, "hs", &pki, "client")
        .spawn()
        .expect("starting ess actor-host");
    for run in ["first", "second"] {
        let out = tmp.path().join(run);
        let o = Command::new(ess_bin())
            .args(train_args(
                &out,
                &["--actors", "1", "--config", cfg.to_str().unwrap()],
            ))
            .env("RUST_LOG", "warn,ess_learner::remote=info")
            .output()
            .unwrap();
        let log = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{run} run: {log}");
        assert!(
            log.contains("actor host joined host=hs"),
            "the host serves the {run} run: {log}"
        );
        assert!(!log.contains("actor host lost"), "{log}");
        assert_eq!(
            host.try_wait().unwrap(),
            None,
            "the host waits for the next run"
        );
    }
    let pid = nix::unistd::Pid::from_raw(host.id() as i32);
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGINT).unwrap();
    let (code, log) = host_log(host, 20);
    assert_eq!(code, Some(0), "Ctrl-C ends the host: {log}");
    assert_eq!(
        log.matches("actor processes started for the run").count(),
        2,
        "{log}"
    );
    assert!(log.contains("waiting for the next run"), "{log}");
    assert!(!log.contains("without STOP"), "{log}");
}

#[test]
fn bad_remote_settings_are_one_line_naming_them_exit_2() {
    let tmp = tempfile::tempdir().unwrap();
    let pki = Pki::new();
    let host = |learner: &str, name: &str, ca: &Path| {
        let mut args = vec!["actor-host", "--learner", learner, "--name", name];
        args.extend(["--tls-ca", ca.to_str().unwrap()]);
        let (cert, key) = (pki.path("client.pem"), pki.path("client.key"));
        args.extend(["--tls-cert", cert.to_str().unwrap()]);
        args.extend(["--tls-key", key.to_str().unwrap()]);
        ess(&args)
    };
    let ca = pki.path("ca.pem");
    let cases = [
        (
            host("tcp/127.0.0.1:7447", "a", &ca),
            "--learner `tcp/127.0.0.1:7447`",
        ),
        (host("tls/127.0.0.1:7447", "a/b", &ca), "--name `a/b`"),
        (
            host("tls/127.0.0.1:7447", "a", &tmp.path().join("no.pem")),
            "--tls-ca",
        ),
        (
            host("tls/127.0.0.1:7447", "a", &pki.path("ca.srl")),
            "not PEM",
        ),
    ];
    for (o, says) in &cases {
        assert_eq!(o.status.code(), Some(2), "{}", text(o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains(says) && err.lines().count() == 1,
            "{says}: {err}"
        );
    }
    // The learner's side: refused before any data is prepared.
    let cfg = remote_config(tmp.path(), 7447, &[], &pki);
    let text_cfg = std::fs::read_to_string(&cfg).unwrap();
    let missing = tmp.path().join("missing.pem");
    std::fs::write(
        &cfg,
        text_cfg.replace(
            pki.path("ca.pem").to_str().unwrap(),
            missing.to_str().unwrap(),
        ),
    )
    .unwrap();
    let out = tmp.path().join("run");
    for (args, says) in [
        (vec!["--config", cfg.to_str().unwrap()], "remote.tls_ca"),
        (
            vec!["--set", "remote.listen=tcp/0.0.0.0:7447"],
            "remote.listen",
        ),
        (vec!["--set", "remote.hosts=[\"a\",\"a\"]"], "remote.hosts"),
    ] {
        let mut a = vec!["train", "--out", out.to_str().unwrap()];
        a.extend(args);
        let o = ess(&a);
        assert_eq!(o.status.code(), Some(2), "{}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains(says) && err.lines().count() == 1,
            "{says}: {err}"
        );
    }
    assert!(!out.join("metrics.csv").exists());
}
