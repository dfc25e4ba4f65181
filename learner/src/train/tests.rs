//! The loop's own tests: the CSV rows and resume's refusals.

use super::*;
use ess_proto::config::ConfigBuilder;

struct Quiet;
impl Progress for Quiet {
    fn iteration(&mut self, _: &IterationLog) {}
    fn message(&mut self, _: &str) {}
}

#[test]
fn metrics_csv_has_one_row_per_iteration_and_the_final_evaluation_in_the_last() {
    let mut b = ConfigBuilder::new();
    for kv in [
        "run.iterations=3",
        "run.transport=\"threads\"",
        "run.actors=1",
        "run.eval_every=2",
        "run.rollout_steps=200",
        "disc.steps=2",
        "disc.batch=32",
        "ppo.epochs=1",
        "ppo.minibatch=100",
        "run.eval_episodes=2",
        "run.eval_episodes_periodic=1",
        "run.reference_episodes=2",
        "demos.majority_episodes=4",
        "run.actors=1",
        "run.torch_threads=1",
    ] {
        b.set(kv).expect(kv);
    }
    let cfg = b.build().expect("config");
    let dir = tempfile::tempdir().expect("tmp");
    let out = run(
        &cfg,
        dir.path(),
        crate::logs::open,
        &mut Quiet,
        &AtomicBool::new(false),
    )
    .expect("train");
    let csv = std::fs::read_to_string(dir.path().join("metrics.csv")).expect("csv");
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(CSV_HEADER));
    let col = |name: &str| CSV_HEADER.split(',').position(|c| c == name).expect(name);
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let iterations: Vec<&str> = rows.iter().map(|r| r[0]).collect();
    assert_eq!(iterations, ["1", "2", "3"], "{csv}");
    // Every row holds its iteration's training numbers.
    for r in &rows {
        for name in ["env_steps", "rollout_s", "ppo_s"] {
            let v: f64 = r[col(name)].parse().expect(name);
            assert!(v > 0.0, "{name} = {v} in {r:?}");
        }
    }
    // Periodic evaluation at iteration 2, the final one in iteration 3's row.
    let nmi = |i: usize| rows[i][col("nmi")];
    assert_eq!(nmi(0), "", "{csv}");
    assert!(!nmi(1).is_empty(), "{csv}");
    let final_nmi: f64 = nmi(2).parse().expect("final nmi");
    assert!((final_nmi - out.summary.nmi).abs() < 1e-6, "{csv}");
    let ent: f64 = rows[2][col("ent")].parse().expect("final ent");
    assert!((ent - out.summary.ent).abs() < 1e-6, "{csv}");
}

#[test]
fn resuming_a_directory_without_a_checkpoint_names_what_is_missing() {
    let small = || {
        let mut b = ConfigBuilder::new();
        b.set("run.iterations=2").expect("set");
        b.set("run.transport=\"threads\"").expect("set");
        b.build().expect("config")
    };
    let dir = tempfile::tempdir().expect("tmp");
    let resume_there = || {
        resume(
            dir.path(),
            crate::logs::open,
            &mut Quiet,
            &AtomicBool::new(false),
        )
    };
    let e = resume_there().err().expect("no run there");
    assert!(format!("{e:#}").contains("config.toml"), "{e:#}");
    std::fs::write(dir.path().join("config.toml"), small().to_toml()).expect("w");
    let e = resume_there().err().expect("no checkpoint");
    assert!(format!("{e:#}").contains("no complete checkpoint"), "{e:#}");
}

/// Keeps the progress messages.
#[derive(Default)]
struct Messages(Vec<String>);
impl Progress for Messages {
    fn iteration(&mut self, _: &IterationLog) {}
    fn message(&mut self, m: &str) {
        self.0.push(m.to_owned());
    }
}

#[test]
fn a_fresh_run_clones_the_labeled_demonstrations_only_when_asked() {
    let trainer_messages = |bc_steps: usize| {
        let mut b = ConfigBuilder::new();
        for kv in [
            "run.transport=\"threads\"",
            "run.actors=1",
            "run.reference_episodes=2",
            "demos.majority_episodes=4",
            "ppo.minibatch=64",
            &format!("ppo.bc_steps={bc_steps}"),
        ] {
            b.set(kv).expect(kv);
        }
        let cfg = b.build().expect("config");
        let dir = tempfile::tempdir().expect("tmp");
        let mut p = Messages::default();
        Trainer::new(&cfg, dir.path(), crate::logs::open, &mut p, false).expect("trainer");
        p.0
    };
    let cloning = |m: &Vec<String>| {
        m.iter()
            .find(|m| m.starts_with("behaviour cloning"))
            .cloned()
    };
    assert_eq!(cloning(&trainer_messages(0)), None);
    let line = cloning(&trainer_messages(300)).expect("a cloning message");
    let errors: Vec<f64> = line
        .rsplit("squared error ")
        .next()
        .expect("errors")
        .split(" -> ")
        .map(|v| v.parse().expect(&line))
        .collect();
    assert!(errors[1] < 0.5 * errors[0], "{line}");
}

/// A small Traj2D run's configuration on `backend`.
fn small_run(backend: Backend) -> CheckedConfig {
    small_run_with(backend, &[])
}

/// [`small_run`] with the settings `extra` on top.
fn small_run_with(backend: Backend, extra: &[&str]) -> CheckedConfig {
    let mut b = ConfigBuilder::new();
    for kv in [
        "run.iterations=12",
        "run.transport=\"threads\"",
        "run.actors=1",
        "run.eval_every=0",
        "run.rollout_steps=400",
        "disc.steps=4",
        "disc.batch=64",
        "ppo.epochs=2",
        "ppo.minibatch=100",
        "run.eval_episodes=1",
        "run.reference_episodes=2",
        "demos.majority_episodes=4",
        "run.torch_threads=2",
    ]
    .iter()
    .chain(extra)
    {
        b.set(kv).expect(kv);
    }
    b.build().expect("config").with_backend(backend)
}

/// Iterations `range` of the run in `out` (fresh when it starts at 1, else resumed
/// from its checkpoint), a checkpoint after the last; their rows.
fn iterations(
    cfg: &CheckedConfig,
    out: &Path,
    range: std::ops::RangeInclusive<usize>,
) -> Vec<IterationLog> {
    let resuming = *range.start() > 1;
    let mut t = Trainer::new(cfg, out, crate::logs::open, &mut Quiet, resuming).expect("trainer");
    assert_eq!(t.st.iters_done + 1, *range.start());
    assert_eq!(t.fused.is_some(), cfg.learner.backend == Backend::Fused);
    let mut rows = Vec::new();
    for it in range {
        let log = t.iteration(it).expect("iteration");
        rows.push(log.clone());
        t.record(log, &mut Quiet).expect("record");
    }
    t.checkpoint().expect("checkpoint");
    rows
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for e in std::fs::read_dir(from).expect("read_dir") {
        let e = e.expect("entry");
        let dest = to.join(e.file_name());
        if e.file_type().expect("type").is_dir() {
            copy_dir(&e.path(), &dest);
        } else {
            std::fs::copy(e.path(), dest).expect("copy");
        }
    }
}

/// The losses of an iteration's row, for comparing two continuations.
fn losses(l: &IterationLog) -> [f64; 6] {
    [
        l.disc_bce,
        l.qc_labeled,
        l.qeps,
        l.rim_entropy,
        l.policy_loss,
        l.value_loss,
    ]
}

/// Ten iterations on one backend, a checkpoint, then iteration 11 continued on the
/// other backend and on the same one: both continuations start from the same state
/// (the checkpoint holds the one set of tensors both backends update), so their
/// iteration 11 agrees up to float rounding. Both directions.
#[test]
fn a_checkpoint_of_either_backend_resumes_on_the_other() {
    for (first, other) in [
        (Backend::Fused, Backend::Tch),
        (Backend::Tch, Backend::Fused),
    ] {
        let dir = tempfile::tempdir().expect("tmp");
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        let first_cfg = small_run(first);
        let rows = iterations(&first_cfg, &a, 1..=10);
        assert_eq!(rows.len(), 10);
        copy_dir(&a, &b);
        let same = iterations(&first_cfg, &a, 11..=11);
        let switched = iterations(&small_run(other), &b, 11..=11);
        for (x, y) in losses(&switched[0]).iter().zip(losses(&same[0])) {
            assert!(
                (x - y).abs() <= 1e-4 * y.abs().max(1e-2),
                "{first:?} -> {other:?}: {:?} vs {:?}",
                losses(&switched[0]),
                losses(&same[0])
            );
        }
        // And the switched run goes on from its own checkpoint.
        let more = iterations(&small_run(other), &b, 12..=12);
        assert_eq!(more[0].iteration, 12);
    }
}

/// The cloning error on the demonstrations `split` picks of the policy after four
/// iterations of a small run with `extra` settings (one minibatch of 4096 rows, under
/// the rows' true modes).
fn cloning_error_after_four_iterations(
    backend: Backend,
    extra: &[&str],
    split: fn(&Demos) -> &ess_envs::DemoSplit,
) -> f64 {
    let cfg = small_run_with(backend, extra);
    let dir = tempfile::tempdir().expect("tmp");
    let mut t =
        Trainer::new(&cfg, dir.path(), crate::logs::open, &mut Quiet, false).expect("trainer");
    for it in 1..=4 {
        t.iteration(it).expect("iteration");
    }
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(7);
    let at = (t.dims, cfg.method.use_eps);
    let (rows, ppo) = (split(&t.demos), &mut t.nets.ppo);
    bc::clone_steps(ppo, rows, &t.norm, at, (1, 4096), &mut rng)
        .expect("demos")
        .first
}

/// `ppo.bc_steps_per_iter` keeps the policy near the labeled demonstrations while the
/// rewards train it: after the same iterations (no warm start), the cloning error of
/// the run that takes those steps is well under that of the run that does not, on
/// both backends (the steps run on tch's graph, between fused PPO updates too).
#[test]
fn cloning_after_every_update_keeps_the_policy_near_the_labeled_demos() {
    for backend in [Backend::Fused, Backend::Tch] {
        let error = |per_iter: usize| {
            let kv = format!("ppo.bc_steps_per_iter={per_iter}");
            cloning_error_after_four_iterations(backend, &[&kv], |d| &d.labeled)
        };
        let (without, with) = (error(0), error(100));
        assert!(with < 0.5 * without, "{backend:?}: {with} vs {without}");
    }
}

/// `ppo.bc_unlabeled_steps_per_iter` clones the unlabeled demonstrations under Q_c's
/// codes: after the same iterations, the run that takes those steps is closer to them
/// (measured under their true modes, which training never reads) than the run that
/// does not, on both backends.
#[test]
fn cloning_under_q_c_s_codes_brings_the_policy_near_the_unlabeled_demos() {
    for backend in [Backend::Fused, Backend::Tch] {
        let error = |per_iter: usize| {
            let kv = format!("ppo.bc_unlabeled_steps_per_iter={per_iter}");
            // Enough D/Q steps for Q_c to be sure of most rows by the first update.
            let extra = [kv.as_str(), "disc.steps=100", "disc.lr=0.003"];
            cloning_error_after_four_iterations(backend, &extra, |d| &d.unlabeled)
        };
        let (without, with) = (error(0), error(100));
        assert!(with < 0.5 * without, "{backend:?}: {with} vs {without}");
    }
}
