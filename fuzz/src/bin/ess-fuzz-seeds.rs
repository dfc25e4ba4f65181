//! Writes the seed corpus: `ess-fuzz-seeds DIR [RUN_LOG...]` (see `ess_fuzz::seeds`).

use anyhow::{Context, Result};
use std::path::PathBuf;

fn main() -> Result<()> {
    let mut args = std::env::args_os().skip(1);
    let dir = PathBuf::from(
        args.next()
            .context("usage: ess-fuzz-seeds DIR [RUN_LOG...]")?,
    );
    let run_logs: Vec<PathBuf> = args.map(PathBuf::from).collect();
    let n = ess_fuzz::seeds::write(&dir, &run_logs)?;
    println!("{n} seeds written under {}", dir.display());
    Ok(())
}
