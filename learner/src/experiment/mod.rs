//! `ess experiment SPEC`: a grid of training runs (presets x tasks x variants x seeds)
//! described by a TOML file (`deploy/experiments/`), run to completion and reported as
//! the paper reports it (Tables 1-3, Figs. 5-6).
//!
//! - [`spec`]: the file, its cells, and the checks that refuse a bad spec before
//!   anything runs.
//! - [`run`]: on this machine the cells go through the job manager behind `ess serve`
//!   (its FIFO queue and core budget; stop and resume), one job per cell named after
//!   it, so `<out>/jobs/<cell>/` is the cell's run directory and a second invocation
//!   skips finished cells and resumes interrupted ones. With `--slurm` the same cells
//!   are one Slurm job array (`sbatch --array`), each task running one cell into the
//!   same directory: a cluster's scheduler does the scheduling, Ess writes none of its
//!   own.
//! - [`report`]: mean ± std per table entry beside the paper's number (Markdown) and
//!   the spec's figure (PNG), from whatever cells have finished.
//! - [`compare`]: which rows of a column its seeds can tell apart (exact permutation
//!   test), so "first of seven" is read against the seeds' scatter.

pub mod compare;
pub mod report;
pub mod run;
pub mod spec;

pub use spec::{Cell, ExperimentSpec, SpecError};
