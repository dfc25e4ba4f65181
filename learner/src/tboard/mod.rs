//! TensorBoard event files for a run: `<run>/tb/events.out.tfevents.*`, so that
//! TensorBoard (and W&B's sync from it) shows an Ess run beside cleanrl's or
//! Stable-Baselines3's, live while it trains.
//!
//! What a run writes, each against env steps:
//! - every number of each `metrics.csv` row, when the row is written, under
//!   `<group>/<column>` (the CSV's column name after the slash, [`row_scalars`]), with
//!   p(c) as `prior/p_c<k>`;
//! - each evaluation's normalised reward per code (`eval/normalized_reward_code<k>`);
//! - the run's configuration as text (`config`, at step 0) and its figures
//!   (`trajectories.png`, `curves.png`) as images at the last step.
//!
//! The events are TensorBoard's own messages ([`ess_proto::tensorboard`], compiled from
//! its `.proto` files) in TFRecord framing ([`events`]). A resumed run opens a new file
//! whose first event restarts the log at the checkpoint's step. Writing the event files
//! never stops training: the first failure is reported once and the run goes on
//! without them ([`Board::failed`]).

pub mod events;

use crate::eval::EvalResult;
use crate::train::IterationLog;
use events::{EventFile, EventFileError};
use std::path::Path;

/// The scalars of one `metrics.csv` row, tagged `<group>/<column>`; the step is the
/// row's `env_steps`. Evaluation columns only when the row has them.
pub fn row_scalars(l: &IterationLog) -> Vec<(String, f64)> {
    let mut v: Vec<(String, f64)> = [
        ("progress/iteration", l.iteration as f64),
        ("time/wall_s", l.wall_s),
        ("time/rollout_s", l.rollout_s),
        ("time/disc_s", l.disc_s),
        ("time/ppo_s", l.ppo_s),
        ("losses/disc_bce", l.disc_bce),
        ("disc/d_acc_expert", l.d_acc_expert),
        ("disc/d_acc_policy", l.d_acc_policy),
        ("losses/qc_labeled", l.qc_labeled),
        ("losses/qc_generated", l.qc_generated),
        ("losses/qeps", l.qeps),
        ("losses/rim_entropy", l.rim_entropy),
        ("losses/rim_kl", l.rim_kl),
        ("losses/contrastive", l.contrastive),
        ("policy/reward_mean", l.reward_mean),
        ("policy/policy_loss", l.policy_loss),
        ("policy/value_loss", l.value_loss),
        ("policy/entropy", l.entropy),
        ("policy/approx_kl", l.approx_kl),
    ]
    .into_iter()
    .map(|(t, x)| (t.to_string(), x))
    .collect();
    for (k, p) in l.prior.split(';').enumerate() {
        if let Ok(p) = p.parse::<f64>() {
            v.push((format!("prior/p_c{k}"), p));
        }
    }
    for (tag, x) in [
        ("eval/nmi", l.nmi),
        ("eval/ent", l.ent),
        ("eval/normalized_reward", l.normalized_reward),
    ] {
        if let Some(x) = x {
            v.push((tag.to_string(), x));
        }
    }
    v
}

/// A run's event file, or the note that writing it failed.
pub struct Board {
    file: Option<EventFile>,
    /// The first failure, to report once (taken by [`Board::failed`]).
    failure: Option<String>,
}

impl Board {
    /// The event file of the run in `run_dir` (`tb/` under it). `resumed_at`: the step
    /// a resumed run continues from.
    pub fn open(run_dir: &Path, resumed_at: Option<usize>) -> Self {
        let mut b = Self {
            file: None,
            failure: None,
        };
        match EventFile::create(&run_dir.join("tb")) {
            Ok(f) => b.file = Some(f),
            Err(e) => b.fail(e),
        }
        if let Some(step) = resumed_at {
            b.each(|f| f.restart(step as i64));
        }
        b
    }

    fn fail(&mut self, e: EventFileError) {
        self.file = None;
        self.failure = Some(format!(
            "TensorBoard event file not written ({e}); training goes on without it"
        ));
    }

    /// Runs `w` on the file, then flushes; a failure closes the board.
    fn each(&mut self, w: impl FnOnce(&mut EventFile) -> Result<(), EventFileError>) {
        if let Some(f) = self.file.as_mut()
            && let Err(e) = w(f).and_then(|()| f.flush())
        {
            self.fail(e);
        }
    }

    /// The first failure, once: the caller says it to the user.
    pub fn failed(&mut self) -> Option<String> {
        self.failure.take()
    }

    /// The run's configuration (TOML) as text at step 0.
    pub fn config(&mut self, toml: &str) {
        let md = format!("```toml\n{toml}\n```");
        self.each(|f| f.text(0, "config", &md));
    }

    /// One `metrics.csv` row.
    pub fn row(&mut self, l: &IterationLog) {
        let values = row_scalars(l);
        self.each(|f| f.scalars(l.env_steps as i64, &values));
    }

    /// An evaluation at `step` env steps: its normalised reward per code.
    pub fn evaluation(&mut self, step: usize, r: &EvalResult) {
        let values: Vec<(String, f64)> = r
            .normalized_reward_per_code
            .iter()
            .enumerate()
            .map(|(k, &x)| (format!("eval/normalized_reward_code{k}"), x))
            .collect();
        self.each(|f| f.scalars(step as i64, &values));
    }

    /// The PNG at `path` as an image tagged with its file stem, if the file is there.
    pub fn figure(&mut self, step: usize, path: &Path) {
        let Ok(png) = std::fs::read(path) else {
            return;
        };
        let tag = path
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("figure")
            .to_string();
        self.each(|f| f.image(step as i64, &tag, &png).map(|_| ()));
    }
}
