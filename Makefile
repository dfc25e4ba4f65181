# Everything a fresh machine needs goes through scripts/bootstrap.sh (idempotent).
SHELL := /bin/bash
ENV := source .deps/env.sh
# Arguments for `make train`, e.g. make train ARGS="--preset gail --seed 1"
ARGS ?=

.PHONY: bootstrap build train test lint fuzz bench-traj2d clean-runs

bootstrap:
	@bash scripts/bootstrap.sh

build: bootstrap
	@$(ENV) && cargo build --release --locked -p ess-learner --bin ess -p ess-actor --bin ess-actor

## The default training: Ess-InfoGAIL on the 2D trajectory task, seed 0.
train: build
	@$(ENV) && ./target/release/ess train $(ARGS)

## Format first (seconds), then one build that is also the lint pass, then every test
## (unit, golden numbers, cross-process CLI) under cargo-nextest (.config/nextest.toml).
## The build compiles our crates through clippy-driver (what `cargo clippy` runs, here
## as cargo's workspace wrapper), so clippy's lints with -D warnings come out of the same
## compilation that makes the test binaries, instead of a second, metadata-only pass over
## every dependency (about a minute of a fresh make test: bench/tests.md). CLIPPY_ARGS is how
## cargo-clippy hands its `-- -D warnings` to clippy-driver (pinned toolchain:
## rust-toolchain.toml). Same selection and environment for build and nextest, so nextest
## rebuilds nothing. Incremental artifacts are off: they doubled a fresh build's disk.
CLIPPY_BUILD := CARGO_INCREMENTAL=0 RUSTC_WORKSPACE_WRAPPER="$$(rustup which clippy-driver)" \
  CLIPPY_ARGS=-D__CLIPPY_HACKERY__warnings__CLIPPY_HACKERY__
test:
	@bash scripts/bootstrap.sh --nextest
	@$(ENV) && cargo fmt --all --check
	@$(ENV) && $(CLIPPY_BUILD) cargo build --workspace --lib --bins --tests --examples --locked
	@$(ENV) && $(CLIPPY_BUILD) cargo nextest run --workspace --lib --bins --tests --locked

lint: bootstrap
	@$(ENV) && cargo fmt --all --check
	@$(ENV) && cargo clippy --workspace --all-targets --locked -- -D warnings

## Coverage-guided fuzzing of every parser with libFuzzer (cargo-fuzz, nightly):
## FUZZ_SECONDS per target, or FUZZ_RUNS executions if they come first (-1: no limit;
## per worker with FUZZ_JOBS > 1, libFuzzer's jobs mode: that many processes at once);
## new inputs go to fuzz/libfuzzer/corpus, crashes to fuzz/libfuzzer/artifacts
## (bench/fuzz.md). make test runs a short stable version.
FUZZ_SECONDS ?= 300
FUZZ_RUNS ?= -1
FUZZ_JOBS ?= 1
FUZZ_TARGETS ?= config task_file demos runlog shm job_spec
fuzz:
	@bash scripts/bootstrap.sh --fuzz
	@$(ENV) && for t in $(FUZZ_TARGETS); do \
	  mkdir -p fuzz/libfuzzer/corpus/$$t && \
	  cargo +nightly fuzz run --fuzz-dir fuzz/libfuzzer $$t fuzz/libfuzzer/corpus/$$t fuzz/corpus/$$t -- \
	    -max_total_time=$(FUZZ_SECONDS) -runs=$(FUZZ_RUNS) -rss_limit_mb=4096 -max_len=262144 -timeout=10 -print_final_stats=1 \
	    $(if $(filter-out 1,$(FUZZ_JOBS)),-jobs=$(FUZZ_JOBS) -workers=$(FUZZ_JOBS)) \
	    || exit 1; \
	done

## Table 1 (2D column) for all seven presets x 5 seeds: see bench/README.md.
bench-traj2d: build
	@$(ENV) && bash bench/traj2d.sh

clean-runs:
	rm -rf runs
