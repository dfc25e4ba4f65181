//! The control plane: the job manager that owns training jobs on this machine
//! ([`jobs`]), the gRPC server around it (`ess serve`, [`serve`]) and its client
//! (`ess job ...`, [`client`]).

pub mod client;
pub mod jobs;
pub mod serve;
