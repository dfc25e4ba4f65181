//! `ess serve --dashboard`: driven in a real headless browser (Debian's chromium through
//! chromedriver, over WebDriver with the `fantoccini` client; `scripts/bootstrap.sh
//! --nextest` installs both). A wrong token gets nothing; the right one logs in; a job
//! submitted from the page shows its curve growing while it trains; its Cancel button
//! stops it and the page shows the new state. A malformed request gets one 4xx line and
//! changes nothing. With `ESS_SCREENSHOT_DIR` set, the page is saved there as
//! `dashboard.png` (the README's screenshot).

use ess_tests::ess_bin;
use fantoccini::{Client, ClientBuilder, Locator};
use serde_json::json;
use std::io::{BufRead, BufReader};
use std::net::TcpListener;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A child process killed when dropped.
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `ess serve` with a token and the dashboard (and `extra` arguments); returns it and
/// the dashboard's URL.
fn start(dir: &std::path::Path, extra: &[&std::ffi::OsStr]) -> (Killed, String) {
    std::fs::write(dir.join("token"), "s3cret-token\n").unwrap();
    let mut child = Command::new(ess_bin())
        .args([
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--dashboard",
            "127.0.0.1:0",
        ])
        .arg("--token-file")
        .arg(dir.join("token"))
        .arg("--data-dir")
        .arg(dir.join("data"))
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(dir.join("serve.err")).unwrap())
        .spawn()
        .expect("spawning ess serve");
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut lines = [String::new(), String::new()];
    for l in &mut lines {
        out.read_line(l).expect("reading ess serve's stdout");
    }
    let url = lines[1]
        .trim()
        .strip_prefix("dashboard on ")
        .map(str::to_string);
    let url = url.unwrap_or_else(|| panic!("ess serve printed {lines:?}"));
    (Killed(child), url)
}

/// chromedriver on a free port; returns it and its URL.
fn chromedriver() -> (Killed, String) {
    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let child = Command::new("chromedriver")
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("chromedriver (Debian: chromium-driver; `bash scripts/bootstrap.sh --nextest` installs it)");
    let deadline = Instant::now() + Duration::from_secs(20);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            Instant::now() < deadline,
            "chromedriver did not listen on {port}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    (Killed(child), format!("http://127.0.0.1:{port}"))
}

async fn browser(driver: &str, insecure_certs: bool) -> Client {
    let mut caps = serde_json::Map::new();
    let args = [
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--window-size=1280,1000",
    ];
    caps.insert("goog:chromeOptions".into(), json!({ "args": args }));
    caps.insert("acceptInsecureCerts".into(), json!(insecure_certs));
    let http = hyper_util::client::legacy::connect::HttpConnector::new();
    ClientBuilder::new(http)
        .capabilities(caps)
        .connect(driver)
        .await
        .expect("a chromium session")
}

/// Polls `check` every 200 ms until it gives `Some`, for at most `secs`.
async fn wait_for<T, F, Fut>(secs: u64, what: &str, mut check: F) -> T
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Option<T>>,
{
    let deadline = Instant::now() + Duration::from_secs(secs);
    loop {
        if let Some(v) = check().await {
            return v;
        }
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

/// The number of points of job `id`'s curve on the page (0 while none is drawn).
async fn points(c: &Client, id: &str) -> usize {
    let sel = format!("polyline[id='curve-{id}']");
    match c.find(Locator::Css(&sel)).await {
        Ok(e) => e
            .attr("data-points")
            .await
            .ok()
            .flatten()
            .and_then(|p| p.parse().ok())
            .unwrap_or(0),
        Err(_) => 0,
    }
}

async fn log_in(c: &Client, url: &str, token: &str) {
    c.goto(&format!("{url}login")).await.unwrap();
    c.find(Locator::Id("token"))
        .await
        .unwrap()
        .send_keys(token)
        .await
        .unwrap();
    c.find(Locator::Id("login"))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_browser_logs_in_watches_a_job_train_and_cancels_it() {
    let dir = tempfile::tempdir().unwrap();
    let (_serve, url) = start(dir.path(), &[]);
    let (_driver, driver_url) = chromedriver();
    let c = browser(&driver_url, false).await;

    // No session: the page sends the browser to the login, the API answers 401.
    c.goto(&url).await.unwrap();
    assert!(c.current_url().await.unwrap().as_str().ends_with("/login"));
    log_in(&c, &url, "wrong-token").await;
    // The click returns before the POST's answer is loaded: wait for it (CI once
    // looked for the message on the old page and failed).
    let err = wait_for(10, "the login to say the token is wrong", || async {
        c.find(Locator::Id("error")).await.ok()
    })
    .await;
    assert_eq!(err.text().await.unwrap(), "Wrong token.");
    c.goto(&format!("{url}api/jobs")).await.unwrap();
    let body = c
        .find(Locator::Css("body"))
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        body.contains("log in first") && !body.contains("jobs"),
        "{body}"
    );

    // The right token: the page, empty.
    log_in(&c, &url, "s3cret-token").await;
    wait_for(10, "the jobs page", || async {
        let u = c.current_url().await.ok()?;
        (u.path() == "/").then_some(())
    })
    .await;

    // Submit from the page: a Traj2D run long enough to watch.
    c.find(Locator::Id("env"))
        .await
        .unwrap()
        .send_keys("traj2d")
        .await
        .unwrap();
    c.find(Locator::Id("seed"))
        .await
        .unwrap()
        .send_keys("4")
        .await
        .unwrap();
    let overrides = "run.iterations=3000\nrun.actors=0\nrun.eval_every=0\nrun.rollout_steps=1000";
    c.find(Locator::Id("overrides"))
        .await
        .unwrap()
        .send_keys(overrides)
        .await
        .unwrap();
    c.find(Locator::Id("submit-button"))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
    let row = "tr[data-id='job-1']";
    let state = wait_for(60, "job-1 running", || async {
        let s = c
            .find(Locator::Css(&format!("{row} td.state")))
            .await
            .ok()?;
        let t = s.text().await.ok()?;
        t.starts_with("running").then_some(t)
    })
    .await;
    assert!(state.starts_with("running"), "{state}");

    // Its curve grows while it trains.
    let first = wait_for(90, "job-1's first points", || async {
        let n = points(&c, "job-1").await;
        (n >= 2).then_some(n)
    })
    .await;
    let later = wait_for(60, "job-1's curve to grow", || async {
        let n = points(&c, "job-1").await;
        (n > first + 2).then_some(n)
    })
    .await;
    assert!(later > first);
    if let Some(shots) = std::env::var_os("ESS_SCREENSHOT_DIR") {
        let png = c.screenshot().await.unwrap();
        std::fs::write(std::path::Path::new(&shots).join("dashboard.png"), png).unwrap();
    }

    // A malformed submission: one 4xx line, no new job.
    let status: serde_json::Value = c
        .execute(
            "return fetch('/api/jobs', {method: 'POST', body: '{\"seed\": \"x\"}'})
               .then(r => r.json().then(b => [r.status, b.error]))",
            vec![],
        )
        .await
        .unwrap();
    assert_eq!(status[0], 400, "{status}");
    assert!(status[1].as_str().unwrap().starts_with("seed:"), "{status}");

    // Cancel: the row shows the job stopping, then stopped.
    c.find(Locator::Css(&format!("{row} button.cancel")))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
    wait_for(120, "job-1 stopped", || async {
        let s = c
            .find(Locator::Css(&format!("{row} td.state")))
            .await
            .ok()?;
        (s.text().await.ok()? == "stopped").then_some(())
    })
    .await;
    let rows = c.find_all(Locator::Css("tbody#jobs tr")).await.unwrap();
    assert_eq!(rows.len(), 1, "the malformed submission made no job");
    c.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_tls_the_dashboard_is_served_over_https_only() {
    let dir = tempfile::tempdir().unwrap();
    let pki = ess_tests::pki::Pki::new();
    let (cert, key) = (pki.path("server.pem"), pki.path("server.key"));
    let extra = [
        "--tls-cert".as_ref(),
        cert.as_os_str(),
        "--tls-key".as_ref(),
        key.as_os_str(),
    ];
    let (_serve, url) = start(dir.path(), &extra);
    assert!(url.starts_with("https://"), "{url}");
    let (_driver, driver_url) = chromedriver();
    // The test CA is not the browser's: accept it, as a user would add it.
    let c = browser(&driver_url, true).await;
    c.goto(&url).await.unwrap();
    assert!(c.current_url().await.unwrap().as_str().ends_with("/login"));
    assert!(
        c.find(Locator::Id("token")).await.is_ok(),
        "the login page over TLS"
    );
    // Plain HTTP to the same port gets no page.
    c.goto(&url.replace("https://", "http://")).await.ok();
    assert!(
        c.find(Locator::Id("token")).await.is_err(),
        "a page over plain HTTP"
    );
    c.close().await.unwrap();
}

#[test]
fn a_bad_dashboard_address_is_one_line_and_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    for (addr, says) in [
        ("nonsense", "--dashboard `nonsense`: expected IP:PORT"),
        (
            "0.0.0.0:0",
            "--dashboard 0.0.0.0:0 is reachable from other machines",
        ),
    ] {
        let o = Command::new(ess_bin())
            .args([
                "serve",
                "--listen",
                "127.0.0.1:0",
                "--dashboard",
                addr,
                "--data-dir",
            ])
            .arg(dir.path().join("d"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(
            err.contains(says) && err.trim().lines().count() == 1,
            "{err}"
        );
    }
}
