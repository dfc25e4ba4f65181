//! Log set-up shared by both binaries (`ess` and `ess-actor`): `tracing` to standard
//! error, filtered by `RUST_LOG` (default `warn`), with colours only when standard error
//! is a terminal and `NO_COLOR` is unset (https://no-color.org), so logs redirected to a
//! file or piped (an actor's, through the learner) carry no escape codes.

use std::io::IsTerminal;

/// Installs the global subscriber; call once, first thing in `main`.
pub fn init() {
    let colour = std::io::stderr().is_terminal()
        && std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty());
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(colour)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .init();
}
