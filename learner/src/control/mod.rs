//! The control plane: the job manager that owns training jobs on this machine
//! ([`jobs`]), the gRPC server around it (`ess serve`, [`serve`]) and its client
//! (`ess job ...`, [`client`]), the browser dashboard beside it ([`dashboard`]), and
//! the TLS both sides speak off loopback ([`tls`]).

pub mod client;
pub mod dashboard;
pub mod jobs;
pub mod serve;
pub mod tls;
