//! Helpers for the cross-process tests in `tests/tests/`: they run the real `ess`
//! binary (built by `make test` before the tests) and check what it prints and writes.

pub mod pki;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

/// Path of the `ess` binary: `$ESS_BIN`, else the one beside this test executable's
/// profile directory (`target/<profile>/ess`).
pub fn ess_bin() -> PathBuf {
    if let Ok(p) = std::env::var("ESS_BIN") {
        return PathBuf::from(p);
    }
    let exe = std::env::current_exe().expect("test executable path");
    // target/<profile>/deps/<test-exe>
    let profile_dir = exe
        .parent()
        .and_then(|d| d.parent())
        .expect("target/<profile> directory");
    let bin = profile_dir.join("ess");
    assert!(
        bin.exists(),
        "{} not found: build it first (`cargo build -p ess-learner --bin ess`, as `make test` does) or set ESS_BIN",
        bin.display()
    );
    bin
}

/// Path of the `ess-actor` binary: `$ESS_ACTOR_BIN`, else beside `ess`.
pub fn actor_bin() -> PathBuf {
    if let Ok(p) = std::env::var("ESS_ACTOR_BIN") {
        return PathBuf::from(p);
    }
    let bin = ess_bin().with_file_name("ess-actor");
    assert!(
        bin.exists(),
        "{} not found: build it first (`cargo build -p ess-actor --bin ess-actor`, as `make test` does) or set ESS_ACTOR_BIN",
        bin.display()
    );
    bin
}

/// Direct children of process `pid` (Linux `/proc`).
pub fn children_of(pid: u32) -> Vec<u32> {
    let mut out = Vec::new();
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return out;
    };
    for t in tasks.flatten() {
        if let Ok(s) = std::fs::read_to_string(t.path().join("children")) {
            out.extend(s.split_whitespace().filter_map(|x| x.parse::<u32>().ok()));
        }
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// True while process `pid` runs (a zombie, exited but not yet reaped, counts as gone).
pub fn is_running(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        // Format: `pid (comm) state ...`; comm may hold spaces, so split after `)`.
        Ok(s) => s
            .rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().next())
            .is_some_and(|state| state != "Z" && state != "X"),
        Err(_) => false,
    }
}

/// Waits up to `secs` for every pid in `pids` to stop running; returns those still running.
pub fn wait_gone(pids: &[u32], secs: f64) -> Vec<u32> {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs_f64(secs);
    loop {
        let left: Vec<u32> = pids.iter().copied().filter(|&p| is_running(p)).collect();
        if left.is_empty() || std::time::Instant::now() >= deadline {
            return left;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

/// Runs `ess` with `args`; returns its output.
pub fn ess(args: &[&str]) -> Output {
    Command::new(ess_bin())
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("running ess")
}

/// Where the outside Python packages the tests check against (onnxruntime, numpy,
/// TensorBoard's event reader) were installed: `.deps/pytest` (`scripts/bootstrap.sh
/// --nextest`, which `make test` runs), or `$ESS_TEST_PYTHONPATH`.
pub fn pytest_path() -> PathBuf {
    match std::env::var_os("ESS_TEST_PYTHONPATH") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../.deps/pytest"),
    }
}

/// Runs the Python `script` (`python3 -c`, or `$PYTHON`) with `args`, on
/// [`pytest_path`] only (no user site packages); returns its output.
pub fn python(script: &str, args: &[&std::ffi::OsStr]) -> Output {
    Command::new(std::env::var("PYTHON").unwrap_or_else(|_| "python3".into()))
        .arg("-c")
        .arg(script)
        .args(args)
        .env("PYTHONPATH", pytest_path())
        .env("PYTHONNOUSERSITE", "1")
        .output()
        .expect("python3 runs")
}

/// Settings that make a training run take seconds: for smoke tests only.
pub const SMOKE: &[&str] = &[
    "--set",
    "run.iterations=2",
    "--set",
    "run.rollout_steps=400",
    "--set",
    "disc.steps=3",
    "--set",
    "disc.batch=64",
    "--set",
    "ppo.epochs=2",
    "--set",
    "ppo.minibatch=200",
    "--set",
    "run.eval_episodes=2",
    "--set",
    "run.eval_every=1",
    "--set",
    "run.eval_episodes_periodic=1",
    "--set",
    "demos.majority_episodes=20",
    "--set",
    "run.torch_threads=1",
];

/// Starts `ess serve --listen 127.0.0.1:0 ARGS` (stdout piped, stderr into
/// `stderr_path`, `RUST_LOG=info`) and reads the bound address from its first line.
pub fn start_serve(args: &[&std::ffi::OsStr], stderr_path: &Path) -> (Child, String) {
    use std::io::{BufRead, BufReader};
    let mut child = Command::new(ess_bin())
        .args(["serve", "--listen", "127.0.0.1:0"])
        .args(args)
        .env("RUST_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(stderr_path).expect("creating the server's log"))
        .spawn()
        .expect("spawning ess serve");
    let mut line = String::new();
    let stdout = child.stdout.take().expect("piped stdout");
    BufReader::new(stdout)
        .read_line(&mut line)
        .expect("reading the server's first line");
    let addr = line
        .trim()
        .strip_prefix("listening on ")
        .map(str::to_string);
    match addr {
        Some(a) => (child, a),
        None => {
            let _ = child.kill();
            panic!(
                "first line `{line}`; stderr: {}",
                std::fs::read_to_string(stderr_path).unwrap_or_default()
            )
        }
    }
}
