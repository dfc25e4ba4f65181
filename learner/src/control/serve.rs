//! `ess serve`: the gRPC control plane. [`serve`] takes a bound listener and a shutdown
//! future (so tests drive it in-process) and serves
//!
//! - `ess.v1.JobService` over a [`Manager`] (behind the bearer-token check when a
//!   token is configured: `authorization: Bearer <token>`, compared in constant time);
//! - standard gRPC health (`grpc.health.v1.Health`: `ess.v1.JobService` is SERVING
//!   while the server runs) and reflection (`grpc.reflection.v1`, and `v1alpha` for the
//!   tools that still ask for it), both without a token, so `grpcurl -plaintext
//!   HOST:PORT list` works;
//! - over TLS when [`ServeConfig::tls`] is set ([`crate::control::tls`]); a client
//!   speaking plain HTTP/2 to it fails at the handshake.
//!
//! - with [`ServeConfig::dashboard`], the browser dashboard
//!   ([`crate::control::dashboard`]) on a listener of its own, over the same manager
//!   and token, over TLS when the server has TLS.
//!
//! When the shutdown future resolves, health turns NOT_SERVING, running jobs are stopped
//! gracefully ([`Manager::shutdown`]) and the server returns.

use crate::control::jobs::{Manager, ManagerConfig};
use ess_proto::pb;
use ess_proto::pb::job_service_server::{JobService, JobServiceServer};
use std::future::Future;
use std::sync::Arc;
use subtle::ConstantTimeEq;
use tokio_stream::wrappers::{ReceiverStream, TcpListenerStream};
use tonic::{Request, Response, Status};

/// The default address of `ess serve` (and of `ess job --server`).
pub const DEFAULT_LISTEN: &str = "127.0.0.1:50551";

/// What [`serve`] needs beyond its listener.
#[derive(Debug)]
pub struct ServeConfig {
    /// How jobs run.
    pub manager: ManagerConfig,
    /// The bearer token every JobService call must carry; `None`: no auth.
    pub token: Option<String>,
    /// TLS (identity, optional client CA); `None`: plain HTTP/2.
    pub tls: Option<tonic::transport::ServerTlsConfig>,
    /// The dashboard's listener and, when the server has TLS, its TLS settings (the
    /// same certificate and key); `None`: no dashboard.
    pub dashboard: Option<DashboardListener>,
}

/// Where the dashboard listens.
#[derive(Debug)]
pub struct DashboardListener {
    /// The bound listener.
    pub listener: std::net::TcpListener,
    /// TLS for it (the server's certificate and key); `None`: plain HTTP.
    pub tls: Option<Arc<tokio_rustls::rustls::ServerConfig>>,
}

/// The JobService implementation: a thin layer over the [`Manager`].
pub struct JobSvc {
    manager: Arc<Manager>,
}

#[tonic::async_trait]
impl JobService for JobSvc {
    async fn submit_job(
        &self,
        req: Request<pb::SubmitJobRequest>,
    ) -> Result<Response<pb::Job>, Status> {
        let spec = req.into_inner().spec.unwrap_or_default();
        Ok(Response::new(self.manager.submit(spec).await?))
    }

    async fn list_jobs(
        &self,
        req: Request<pb::ListJobsRequest>,
    ) -> Result<Response<pb::ListJobsResponse>, Status> {
        let req = req.into_inner();
        let states: Vec<pb::JobState> = req
            .states
            .iter()
            .enumerate()
            .map(|(i, s)| {
                pb::JobState::try_from(*s).map_err(|_| {
                    Status::invalid_argument(format!("states[{i}]: unknown state {s}"))
                })
            })
            .collect::<Result<_, _>>()?;
        Ok(Response::new(pb::ListJobsResponse {
            jobs: self.manager.list(&states),
        }))
    }

    async fn get_job(&self, req: Request<pb::GetJobRequest>) -> Result<Response<pb::Job>, Status> {
        Ok(Response::new(self.manager.get(&req.into_inner().id)?))
    }

    type WatchJobStream = ReceiverStream<Result<pb::JobEvent, Status>>;

    async fn watch_job(
        &self,
        req: Request<pb::WatchJobRequest>,
    ) -> Result<Response<Self::WatchJobStream>, Status> {
        let rx = self.manager.watch(&req.into_inner().id)?;
        Ok(Response::new(ReceiverStream::new(rx)))
    }

    async fn stop_job(
        &self,
        req: Request<pb::StopJobRequest>,
    ) -> Result<Response<pb::Job>, Status> {
        Ok(Response::new(self.manager.stop(&req.into_inner().id)?))
    }

    async fn resume_job(
        &self,
        req: Request<pb::ResumeJobRequest>,
    ) -> Result<Response<pb::Job>, Status> {
        Ok(Response::new(self.manager.resume(&req.into_inner().id)?))
    }
}

/// The interceptor that checks `authorization: Bearer <token>` (constant-time).
#[derive(Clone)]
pub struct Auth {
    token: Option<Arc<[u8]>>,
}

impl Auth {
    /// Checks against `token`; `None` lets every call through.
    pub fn new(token: Option<&str>) -> Self {
        Self {
            token: token.map(|t| Arc::from(t.as_bytes())),
        }
    }

    /// Whether `req` may pass.
    pub fn check<T>(&self, req: &Request<T>) -> Result<(), Status> {
        let Some(token) = &self.token else {
            return Ok(());
        };
        let given = req
            .metadata()
            .get("authorization")
            .ok_or_else(|| Status::unauthenticated("missing `authorization: Bearer <token>`"))?;
        let given = given
            .to_str()
            .ok()
            .and_then(|v| v.strip_prefix("Bearer "))
            .ok_or_else(|| Status::unauthenticated("`authorization` must be `Bearer <token>`"))?;
        if bool::from(given.as_bytes().ct_eq(token)) {
            Ok(())
        } else {
            Err(Status::unauthenticated("wrong token"))
        }
    }
}

impl tonic::service::Interceptor for Auth {
    fn call(&mut self, req: Request<()>) -> Result<Request<()>, Status> {
        self.check(&req)?;
        Ok(req)
    }
}

/// Serves on `listener` until `shutdown` resolves; then stops the running jobs
/// gracefully and returns.
pub async fn serve(
    listener: tokio::net::TcpListener,
    cfg: ServeConfig,
    shutdown: impl Future<Output = ()> + Send,
) -> anyhow::Result<()> {
    use anyhow::Context;
    let manager = Manager::open(cfg.manager).context("opening the data dir")?;
    let (health, health_svc) = tonic_health::server::health_reporter();
    health.set_serving::<JobServiceServer<JobSvc>>().await;
    let reflection = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(ess_proto::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    let reflection_v1 = reflection()
        .build_v1()
        .context("building the reflection service")?;
    let reflection_v1alpha = reflection()
        .build_v1alpha()
        .context("building the reflection service (v1alpha)")?;
    let jobs = JobServiceServer::with_interceptor(
        JobSvc {
            manager: manager.clone(),
        },
        Auth::new(cfg.token.as_deref()),
    );
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    if let Some(d) = cfg.dashboard {
        let state = crate::control::dashboard::Dashboard::new(
            manager.clone(),
            cfg.token.as_deref(),
            d.tls.is_some(),
        );
        let app = crate::control::dashboard::router(state);
        d.listener
            .set_nonblocking(true)
            .context("dashboard listener")?;
        let listener =
            tokio::net::TcpListener::from_std(d.listener).context("dashboard listener")?;
        tokio::spawn(crate::control::dashboard::serve(
            listener, app, d.tls, stop_rx,
        ));
    }
    let signal = {
        let manager = manager.clone();
        async move {
            shutdown.await;
            let _ = stop_tx.send(true);
            tracing::info!("shutting down");
            health.set_not_serving::<JobServiceServer<JobSvc>>().await;
            manager.shutdown().await;
        }
    };
    let mut builder = tonic::transport::Server::builder();
    if let Some(tls) = cfg.tls {
        builder = builder.tls_config(tls).context("TLS certificate and key")?;
    }
    builder
        .add_service(health_svc)
        .add_service(reflection_v1)
        .add_service(reflection_v1alpha)
        .add_service(jobs)
        .serve_with_incoming_shutdown(TcpListenerStream::new(listener), signal)
        .await
        .context("serving gRPC")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn req_with(auth: Option<&str>) -> Request<()> {
        let mut r = Request::new(());
        if let Some(a) = auth {
            r.metadata_mut().insert("authorization", a.parse().unwrap());
        }
        r
    }

    #[test]
    fn auth_accepts_only_the_exact_bearer_token() {
        let a = Auth::new(Some("s3cret"));
        assert!(a.check(&req_with(Some("Bearer s3cret"))).is_ok());
        for bad in [
            None,
            Some("Bearer s3cre"),
            Some("Bearer s3cret2"),
            Some("s3cret"),
            Some("bearer s3cret"),
        ] {
            let e = a.check(&req_with(bad)).unwrap_err();
            assert_eq!(e.code(), tonic::Code::Unauthenticated, "{bad:?}");
        }
        assert!(Auth::new(None).check(&req_with(None)).is_ok());
    }
}
