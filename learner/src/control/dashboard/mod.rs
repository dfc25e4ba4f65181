//! The dashboard of `ess serve --dashboard ADDR`: a page in the browser over the same
//! job manager as the gRPC JobService, on a port of its own, in the same process.
//!
//! | route | what |
//! |---|---|
//! | `GET /login`, `POST /login` (form `token`) | the login: the server's bearer token sets an `HttpOnly`, `SameSite=Strict` session cookie (`Secure` under TLS) |
//! | `GET /` | the page (`page.html`, embedded): jobs with state, progress, ETA, env steps/s; live curves of one job or several compared on one chart; cancel, requeue, submit |
//! | `GET /api/jobs` | the jobs as JSON |
//! | `GET /api/jobs/{id}/metrics` | the job's `metrics.csv` columns as JSON, for the curves |
//! | `POST /api/jobs/{id}/cancel`, `POST /api/jobs/{id}/requeue` | stop a job (a checkpoint is kept), resume a stopped or failed one |
//! | `POST /api/jobs` | submit: JSON `{"preset", "env", "seed", "config_toml", "overrides": [[key, value]]}` |
//!
//! Without a valid session every page redirects to `/login` and every `/api` call gets
//! 401; with no token configured (a loopback-only server) there is nothing to log in
//! to, as on gRPC. Errors are one JSON line `{"error": "..."}` with a 4xx status, and a
//! refused request changes nothing. The assets are in the binary: nothing is fetched
//! from elsewhere.

use crate::control::jobs::{Error as JobError, Manager};
use axum::Router;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{Html, IntoResponse, Redirect, Response};
use axum::routing::{get, post};
use ess_proto::pb;
use serde_json::{Value, json};
use std::collections::HashSet;
use std::sync::{Arc, Mutex};
use subtle::ConstantTimeEq;

const PAGE: &str = include_str!("page.html");
const LOGIN: &str = include_str!("login.html");
const COOKIE: &str = "ess_session";

/// The dashboard's state: the manager, the token and the sessions logged in.
pub struct Dashboard {
    manager: Arc<Manager>,
    token: Option<Arc<[u8]>>,
    sessions: Mutex<HashSet<String>>,
    /// Served over TLS: the cookie is `Secure`.
    tls: bool,
}

impl Dashboard {
    /// A dashboard over `manager`, logging in with `token` (none: no login).
    pub fn new(manager: Arc<Manager>, token: Option<&str>, tls: bool) -> Arc<Self> {
        Arc::new(Self {
            manager,
            token: token.map(|t| Arc::from(t.as_bytes())),
            sessions: Mutex::new(HashSet::new()),
            tls,
        })
    }

    /// Whether `headers` carry a session cookie of this server (or no login is needed).
    fn allowed(&self, headers: &HeaderMap) -> bool {
        if self.token.is_none() {
            return true;
        }
        let Some(id) = session_cookie(headers) else {
            return false;
        };
        self.sessions.lock().is_ok_and(|s| s.contains(id))
    }

    fn new_session(&self) -> String {
        let id: [u8; 32] = rand::random();
        let id: String = id.iter().map(|b| format!("{b:02x}")).collect();
        if let Ok(mut s) = self.sessions.lock() {
            s.insert(id.clone());
        }
        id
    }
}

/// The value of the session cookie in `headers`.
fn session_cookie(headers: &HeaderMap) -> Option<&str> {
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .find_map(|kv| kv.trim().strip_prefix(COOKIE)?.strip_prefix('='))
}

/// One JSON error line with its status.
fn error(status: StatusCode, msg: impl Into<String>) -> Response {
    (status, axum::Json(json!({ "error": msg.into() }))).into_response()
}

fn job_error(e: JobError) -> Response {
    let status = match &e {
        JobError::InvalidArgument { .. } => StatusCode::BAD_REQUEST,
        JobError::NotFound { .. } => StatusCode::NOT_FOUND,
        JobError::FailedPrecondition { .. } => StatusCode::CONFLICT,
        JobError::ShuttingDown => StatusCode::SERVICE_UNAVAILABLE,
        JobError::Io { .. } => StatusCode::INTERNAL_SERVER_ERROR,
    };
    error(status, e.to_string())
}

/// The router of the dashboard.
pub fn router(d: Arc<Dashboard>) -> Router {
    Router::new()
        .route("/", get(page))
        .route("/login", get(login_page).post(login))
        .route("/api/jobs", get(jobs).post(submit))
        .route("/api/jobs/{id}/metrics", get(metrics))
        .route("/api/jobs/{id}/cancel", post(cancel))
        .route("/api/jobs/{id}/requeue", post(requeue))
        .fallback(|| async { error(StatusCode::NOT_FOUND, "no such page") })
        .with_state(d)
}

async fn page(State(d): State<Arc<Dashboard>>, headers: HeaderMap) -> Response {
    if d.allowed(&headers) {
        Html(PAGE).into_response()
    } else {
        Redirect::to("/login").into_response()
    }
}

async fn login_page() -> Html<String> {
    Html(LOGIN.replace("{{message}}", ""))
}

async fn login(State(d): State<Arc<Dashboard>>, body: String) -> Response {
    let token = form_value(&body, "token");
    let ok = match (&d.token, &token) {
        (None, _) => true,
        (Some(want), Some(given)) => bool::from(given.as_bytes().ct_eq(want)),
        (Some(_), None) => false,
    };
    if !ok {
        let page = LOGIN.replace("{{message}}", "<p id=\"error\">Wrong token.</p>");
        return (StatusCode::UNAUTHORIZED, Html(page)).into_response();
    }
    let secure = if d.tls { "; Secure" } else { "" };
    let cookie = format!(
        "{COOKIE}={}; HttpOnly; SameSite=Strict; Path=/{secure}",
        d.new_session()
    );
    ([(header::SET_COOKIE, cookie)], Redirect::to("/")).into_response()
}

/// The value of `key` in an `application/x-www-form-urlencoded` body.
fn form_value(body: &str, key: &str) -> Option<String> {
    body.split('&').find_map(|kv| {
        let (k, v) = kv.split_once('=')?;
        (k == key).then(|| {
            let v = v.replace('+', " ");
            percent_encoding::percent_decode_str(&v)
                .decode_utf8_lossy()
                .into_owned()
        })
    })
}

/// Runs `f` for a logged-in caller, else 401.
fn guarded(d: &Dashboard, headers: &HeaderMap, f: impl FnOnce() -> Response) -> Response {
    if d.allowed(headers) {
        f()
    } else {
        error(StatusCode::UNAUTHORIZED, "log in first (POST /login)")
    }
}

fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as i64)
}

/// A job as the page shows it: state, progress, env steps/s and ETA from its record.
pub fn job_json(j: &pb::Job, now_ms: i64) -> Value {
    let state = pb::JobState::try_from(j.state).map_or("unknown".into(), |s| {
        s.as_str_name()
            .trim_start_matches("JOB_STATE_")
            .to_lowercase()
    });
    let running = j.state == pb::JobState::Running as i32;
    let end = if j.finished_unix_ms > 0 {
        j.finished_unix_ms
    } else {
        now_ms
    };
    let elapsed_s = (j.started_unix_ms > 0).then(|| (end - j.started_unix_ms) as f64 / 1000.0);
    let steps_per_s = elapsed_s
        .filter(|&e| e > 0.0 && j.env_steps > 0)
        .map(|e| j.env_steps as f64 / e);
    let eta_s = elapsed_s
        .filter(|_| running && j.iteration > 0)
        .map(|e| e * f64::from(j.iterations.saturating_sub(j.iteration)) / f64::from(j.iteration));
    let spec = j.spec.clone().unwrap_or_default();
    json!({
        "id": j.id,
        "state": state,
        "phase": j.phase,
        "iteration": j.iteration,
        "iterations": j.iterations,
        "env_steps": j.env_steps,
        "progress": if j.iterations > 0 { f64::from(j.iteration) / f64::from(j.iterations) } else { 0.0 },
        "steps_per_s": steps_per_s,
        "eta_s": eta_s,
        "preset": spec.preset,
        "env": spec.env,
        "seed": spec.seed,
        "error": j.error,
        "result": j.result.as_ref().map(|r| json!({
            "nmi": r.nmi, "ent": r.ent, "normalized_reward": r.normalized_reward,
        })),
    })
}

async fn jobs(State(d): State<Arc<Dashboard>>, headers: HeaderMap) -> Response {
    guarded(&d, &headers, || {
        let now = now_ms();
        let list: Vec<Value> = d
            .manager
            .list(&[])
            .iter()
            .map(|j| job_json(j, now))
            .collect();
        axum::Json(json!({ "jobs": list })).into_response()
    })
}

/// The `metrics.csv` columns the page draws.
const CURVES: [&str; 8] = [
    "env_steps",
    "nmi",
    "ent",
    "normalized_reward",
    "reward_mean",
    "disc_bce",
    "d_acc_expert",
    "policy_loss",
];

/// `metrics.csv` as the page's columns: one array per column, `null` where empty.
pub fn metrics_json(csv: &str) -> Value {
    let mut lines = csv.lines();
    let head: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let idx: Vec<Option<usize>> = CURVES
        .iter()
        .map(|c| head.iter().position(|h| h == c))
        .collect();
    let mut cols: Vec<Vec<Value>> = vec![Vec::new(); CURVES.len()];
    for line in lines {
        let cells: Vec<&str> = line.split(',').collect();
        for (col, i) in cols.iter_mut().zip(&idx) {
            let v = i
                .and_then(|i| cells.get(i))
                .and_then(|c| c.parse::<f64>().ok())
                .map_or(Value::Null, Value::from);
            col.push(v);
        }
    }
    let map: serde_json::Map<String, Value> = CURVES
        .iter()
        .zip(cols)
        .map(|(c, v)| ((*c).to_string(), Value::from(v)))
        .collect();
    Value::Object(map)
}

async fn metrics(
    State(d): State<Arc<Dashboard>>,
    headers: HeaderMap,
    Path(id): Path<String>,
) -> Response {
    if !d.allowed(&headers) {
        return error(StatusCode::UNAUTHORIZED, "log in first (POST /login)");
    }
    let job = match d.manager.get(&id) {
        Ok(j) => j,
        Err(e) => return job_error(e),
    };
    let csv = std::path::Path::new(&job.run_dir).join("metrics.csv");
    // Before the first iteration there is no file yet: no points.
    let text = tokio::fs::read_to_string(&csv).await.unwrap_or_default();
    axum::Json(metrics_json(&text)).into_response()
}

/// A job action for a logged-in caller: the job after it, or the manager's refusal.
fn job_action(
    d: &Dashboard,
    headers: &HeaderMap,
    act: impl FnOnce(&Arc<Manager>) -> Result<pb::Job, JobError>,
) -> Response {
    guarded(d, headers, || match act(&d.manager) {
        Ok(j) => axum::Json(job_json(&j, now_ms())).into_response(),
        Err(e) => job_error(e),
    })
}

async fn cancel(
    State(d): State<Arc<Dashboard>>,
    headers: HeaderMap,
    Path(id): Path<String>,
) -> Response {
    job_action(&d, &headers, |m| m.stop(&id))
}

async fn requeue(
    State(d): State<Arc<Dashboard>>,
    headers: HeaderMap,
    Path(id): Path<String>,
) -> Response {
    job_action(&d, &headers, |m| m.resume(&id))
}

/// A submitted spec from the page's JSON.
pub fn spec_from_json(body: &str) -> Result<pb::JobSpec, String> {
    let v: Value = serde_json::from_str(body).map_err(|e| format!("body: not JSON: {e}"))?;
    let obj = v.as_object().ok_or("body: expected a JSON object")?;
    let text = |k: &str| -> Result<String, String> {
        match obj.get(k) {
            None | Some(Value::Null) => Ok(String::new()),
            Some(Value::String(s)) => Ok(s.clone()),
            Some(other) => Err(format!("{k}: expected a string, got {other}")),
        }
    };
    let seed = match obj.get("seed") {
        None | Some(Value::Null) => None,
        Some(s) => Some(
            s.as_u64()
                .ok_or(format!("seed: expected an integer >= 0, got {s}"))?,
        ),
    };
    let mut overrides = Vec::new();
    if let Some(list) = obj.get("overrides").filter(|v| !v.is_null()) {
        let list = list
            .as_array()
            .ok_or("overrides: expected [[key, value], ...]")?;
        for (i, kv) in list.iter().enumerate() {
            let pair = kv.as_array().filter(|p| p.len() == 2);
            let (k, v) = pair
                .and_then(|p| Some((p[0].as_str()?, p[1].as_str()?)))
                .ok_or(format!(
                    "overrides[{i}]: expected [key, value] strings, got {kv}"
                ))?;
            overrides.push(pb::Override {
                key: k.into(),
                value: v.into(),
            });
        }
    }
    for k in obj.keys() {
        if !["preset", "env", "seed", "config_toml", "overrides"].contains(&k.as_str()) {
            return Err(format!("{k}: unknown field"));
        }
    }
    Ok(pb::JobSpec {
        preset: text("preset")?,
        env: text("env")?,
        seed,
        overrides,
        config_toml: text("config_toml")?,
    })
}

async fn submit(State(d): State<Arc<Dashboard>>, headers: HeaderMap, body: String) -> Response {
    if !d.allowed(&headers) {
        return error(StatusCode::UNAUTHORIZED, "log in first (POST /login)");
    }
    let spec = match spec_from_json(&body) {
        Ok(s) => s,
        Err(e) => return error(StatusCode::BAD_REQUEST, e),
    };
    match d.manager.submit(spec).await {
        Ok(j) => (StatusCode::CREATED, axum::Json(job_json(&j, now_ms()))).into_response(),
        Err(e) => job_error(e),
    }
}

/// Serves `app` on `listener` (over TLS with `tls`) until `stop` turns true.
pub async fn serve(
    listener: tokio::net::TcpListener,
    app: Router,
    tls: Option<Arc<tokio_rustls::rustls::ServerConfig>>,
    mut stop: tokio::sync::watch::Receiver<bool>,
) {
    let Some(tls) = tls else {
        let shutdown = async move {
            let _ = stop.wait_for(|s| *s).await;
        };
        if let Err(e) = axum::serve(listener, app)
            .with_graceful_shutdown(shutdown)
            .await
        {
            tracing::warn!("dashboard: {e}");
        }
        return;
    };
    let acceptor = tokio_rustls::TlsAcceptor::from(tls);
    loop {
        let (tcp, peer) = tokio::select! {
            r = listener.accept() => match r {
                Ok(c) => c,
                Err(e) => { tracing::warn!("dashboard: accept: {e}"); continue; }
            },
            _ = stop.wait_for(|s| *s) => return,
        };
        let (acceptor, app) = (acceptor.clone(), app.clone());
        tokio::spawn(async move {
            // A client that fails the handshake (plain HTTP to the TLS port, an
            // unknown CA) is dropped; the server goes on.
            let Ok(stream) = acceptor.accept(tcp).await else {
                tracing::debug!(%peer, "dashboard: TLS handshake failed");
                return;
            };
            let io = hyper_util::rt::TokioIo::new(stream);
            let svc = hyper_util::service::TowerToHyperService::new(app);
            let conn =
                hyper_util::server::conn::auto::Builder::new(hyper_util::rt::TokioExecutor::new());
            if let Err(e) = conn.serve_connection(io, svc).await {
                tracing::debug!(%peer, "dashboard connection: {e}");
            }
        });
    }
}

#[cfg(test)]
mod tests;
