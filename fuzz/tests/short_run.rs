//! The short fuzz run of `make test`: each target's corpus (seeds and every input a
//! fuzzer found a bug with), then random mutations of it (`ess_fuzz::mutate`).

use ess_fuzz::{TARGETS, Target, mutate};

/// Mutations per target: a few seconds each in a test build.
const EXECS: usize = 2000;

fn short_run(name: &str, target: Target) {
    let corpus = mutate::corpus(name).unwrap_or_else(|e| panic!("corpus of {name}: {e}"));
    assert!(!corpus.is_empty(), "fuzz/corpus/{name} has no seeds");
    let seeds: Vec<Vec<u8>> = corpus.into_iter().map(|(_, b)| b).collect();
    if let Err(f) = mutate::run(target, &seeds, EXECS, 0x5eed) {
        let dir = std::env::temp_dir().join("ess-fuzz-findings");
        std::fs::create_dir_all(&dir).expect("findings dir");
        let path = dir.join(format!("{name}-{}", f.input.len()));
        std::fs::write(&path, &f.input).expect("write finding");
        panic!("{name}: {} (input saved to {})", f.message, path.display());
    }
}

macro_rules! short_runs {
    ($($name:ident),*) => {$(
        #[test]
        fn $name() {
            let (name, target) = TARGETS
                .iter()
                .find(|(n, _)| *n == stringify!($name))
                .expect("a target of that name");
            short_run(name, *target);
        }
    )*};
}

short_runs!(config, task_file, demos, runlog, shm, job_spec);

#[test]
fn every_target_has_a_short_run_and_a_libfuzzer_harness() {
    let harness = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("libfuzzer/fuzz_targets");
    for (name, _) in TARGETS {
        let file = harness.join(format!("{name}.rs"));
        let text =
            std::fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        assert!(
            text.contains(&format!("ess_fuzz::{name}(")),
            "{}",
            file.display()
        );
    }
}
