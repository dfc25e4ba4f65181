//! A disk that fills mid-run: the run ends with one clear error naming the file and the
//! OS reason, leaves no partial checkpoint behind, and its last complete checkpoint
//! resumes to the end. The run directory is a 1.5 MB tmpfs mounted in a private mount
//! namespace (`unshare -rm`, so no root and no trace on the host).

use ess_tests::{SMOKE, ess, ess_bin};
use std::path::Path;
use std::process::Command;

const ITERATIONS: usize = 20;

/// `ess train ARGS --out MNT/run` on a fresh tmpfs of `size` at `mnt`; the run's stderr
/// and exit code go to `dir/err` and `dir/rc`, and the run directory is copied to
/// `dir/copy` before the namespace (and its tmpfs) goes away.
fn train_on_tmpfs(dir: &Path, size: &str, args: &[String]) {
    let script = r#"mount -t tmpfs -o "size=$SIZE" ess-disk-full "$MNT" || exit 97
"$@" --out "$MNT/run" 2> "$DIR/err"
echo $? > "$DIR/rc"
cp -a "$MNT/run" "$DIR/copy""#;
    let mnt = dir.join("mnt");
    std::fs::create_dir_all(&mnt).unwrap();
    let out = Command::new("unshare")
        .args(["-rm", "sh", "-c", script, "sh"])
        .arg(ess_bin())
        .args(args)
        .env("SIZE", size)
        .env("MNT", &mnt)
        .env("DIR", dir)
        .env("RUST_LOG", "warn")
        .output()
        .expect("running unshare (util-linux)");
    assert!(
        out.status.success(),
        "a private tmpfs could not be mounted (unshare -rm, then mount -t tmpfs): {:?} {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_disk_that_fills_mid_run_ends_it_clearly_and_the_last_checkpoint_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let mut args: Vec<String> = ["train", "--env", "traj2d", "--actors", "0"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    args.extend(SMOKE.iter().map(|s| s.to_string()));
    for set in [
        format!("run.iterations={ITERATIONS}"),
        "run.checkpoint_every=1".into(),
        "run.eval_every=1000".into(),
    ] {
        args.extend(["--set".to_string(), set]);
    }
    train_on_tmpfs(dir.path(), "1500k", &args);

    let rc = std::fs::read_to_string(dir.path().join("rc")).unwrap();
    let err = std::fs::read_to_string(dir.path().join("err")).unwrap();
    assert_eq!(rc.trim(), "1", "the run did not fail: {err}");
    let errors: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(errors.len(), 1, "{err}");
    assert!(
        errors[0].contains("No space left on device") && errors[0].contains("mnt/run/"),
        "the error names neither the reason nor the file: {err}"
    );
    assert!(!err.contains("I/O error from writing"), "{err}");

    let copy = dir.path().join("copy");
    let mut done: Vec<String> = std::fs::read_dir(copy.join("checkpoints"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    done.sort();
    assert!(
        !done.iter().any(|n| n.ends_with(".tmp")),
        "a partial checkpoint was left behind: {done:?}"
    );
    assert!(
        !done.is_empty() && done.len() < ITERATIONS,
        "the disk did not fill mid-run: {done:?}"
    );

    let resumed = ess(&["train", "--resume", copy.to_str().unwrap()]);
    assert!(
        resumed.status.success(),
        "the last complete checkpoint ({}) did not resume: {}",
        done.last().unwrap(),
        String::from_utf8_lossy(&resumed.stderr)
    );
    let last = copy.join(format!("checkpoints/iter-{ITERATIONS:06}"));
    assert!(
        last.join("state.json").is_file(),
        "the resumed run did not finish"
    );
}
