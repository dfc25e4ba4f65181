//! An actor process's standard error: passed through to the learner's own, line by line,
//! with its last lines kept so that the error naming a dead actor also says why it died
//! (e.g. the dynamic loader's "cannot open shared object file" behind an exit status of
//! 127, which otherwise scrolled past above three restarts).

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Write};
use std::process::ChildStderr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Lines kept per actor process.
const KEPT: usize = 3;

/// How long [`StderrTail::explain`] waits for an exited child's last lines to be read.
const DRAIN: Duration = Duration::from_millis(500);

/// The last lines an actor wrote to its standard error.
#[derive(Clone, Default)]
pub(super) struct StderrTail {
    lines: Arc<Mutex<VecDeque<String>>>,
    /// The pipe reached its end (the child and its children closed it).
    closed: Arc<AtomicBool>,
}

impl StderrTail {
    /// Starts a thread that copies `stderr` to this process's standard error and keeps
    /// its last lines; it ends when the child closes the pipe (exits).
    pub(super) fn follow(stderr: ChildStderr) -> Self {
        let tail = Self::default();
        let keep = tail.clone();
        let spawned = std::thread::Builder::new()
            .name("actor-stderr".into())
            .spawn(move || keep.copy_lines(stderr));
        if let Err(e) = spawned {
            tracing::warn!("cannot follow an actor's standard error: {e}");
        }
        tail
    }

    fn copy_lines(&self, stderr: ChildStderr) {
        let mut reader = BufReader::new(stderr);
        let mut buf = Vec::new();
        // Bytes, not `lines()`: one non-UTF-8 byte must not end the copying.
        while matches!(reader.read_until(b'\n', &mut buf), Ok(n) if n > 0) {
            let line = String::from_utf8_lossy(&buf)
                .trim_end_matches('\n')
                .to_string();
            buf.clear();
            let _ = writeln!(std::io::stderr().lock(), "{line}");
            if let Ok(mut q) = self.lines.lock() {
                if q.len() == KEPT {
                    q.pop_front();
                }
                q.push_back(line);
            }
        }
        self.closed.store(true, Ordering::Release);
    }

    /// `why`, followed by the last lines the process wrote (if any), on one line. Called
    /// once the process exited: waits briefly for the copier to read what it left.
    pub(super) fn explain(&self, why: String) -> String {
        let start = Instant::now();
        while !self.closed.load(Ordering::Acquire) && start.elapsed() < DRAIN {
            std::thread::sleep(Duration::from_millis(5));
        }
        let lines: Vec<String> = match self.lines.lock() {
            Ok(q) => q.iter().map(|l| l.trim().to_string()).collect(),
            Err(_) => Vec::new(),
        };
        let lines: Vec<String> = lines.into_iter().filter(|l| !l.is_empty()).collect();
        if lines.is_empty() {
            why
        } else {
            format!("{why}; its last output: {}", lines.join(" | "))
        }
    }
}
