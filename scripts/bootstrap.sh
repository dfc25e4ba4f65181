#!/usr/bin/env bash
# Idempotent set-up: installs, from the package registries only, what the build needs
# into .deps/ (git-ignored) and writes .deps/env.sh with the variables to export.
#   - libtorch from PyPI's torch==2.11.0 (what tch =0.24.0 links against), plus the two
#     CUDA runtime libraries libtorch_cpu.so needs even on CPU;
#   - MuJoCo 3.17.0's shared library from PyPI's mujoco==3.17.0 wheel (for mujoco-rs).
#   - CMake from PyPI's cmake wheel when none is on PATH: hdf5-metno builds a static
#     HDF5 from source with it (for `ess demos import` of Minari datasets).
#   - with --nextest (what `make test` passes): cargo-nextest (crates.io, `cargo
#     install --locked`, into ~/.cargo/bin) when `cargo nextest` is missing, and a check
#     that the `openssl` command the TLS tests make certificates with is there;
#     Debian's chromium and chromium-driver (apt; root or sudo) for the dashboard's
#     headless-browser test; and
#     onnxruntime + numpy + tensorboard + mcap + foxglove-schemas-protobuf from PyPI
#     into .deps/pytest, the outside readers the tests check Ess's files with (the ONNX
#     export runs in onnxruntime, the event files are read by TensorBoard's loader, the
#     run log's 3D scene by mcap's reader and Foxglove's classes; tests only: `ess`
#     never calls Python).
#   - with --fuzz (what `make fuzz` passes): cargo-fuzz (crates.io) when missing, and a
#     check that a nightly toolchain is installed (libFuzzer's instrumentation needs
#     it; `make test`'s short fuzz run does not).
#   - with --slurm only: Debian's slurm-wlm and munge (apt; root or sudo), for
#     `ess experiment --slurm` on this machine and bench/slurm_grid.sh. Nothing else
#     needs them.
# Safe to run any number of times: each step is skipped when its result is in place.
set -euo pipefail

with_nextest=0
if [ "${1:-}" = "--nextest" ]; then
  with_nextest=1
  shift
fi
with_fuzz=0
if [ "${1:-}" = "--fuzz" ]; then
  with_fuzz=1
  shift
fi

if [ "${1:-}" = "--slurm" ]; then
  if command -v slurmctld >/dev/null 2>&1 && command -v munged >/dev/null 2>&1; then
    printf 'bootstrap: slurm-wlm and munge already installed\n' >&2
    exit 0
  fi
  sudo=""
  [ "$(id -u)" = 0 ] || sudo="sudo"
  printf 'bootstrap: installing slurm-wlm and munge (apt)\n' >&2
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends slurm-wlm munge
  exit 0
fi

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
deps="$root/.deps"
py_dir="$deps/py"
mj_dir="$deps/mujoco"
TORCH_VERSION=2.11.0
MUJOCO_VERSION=3.17.0
CMAKE_VERSION=4.4.5
cmake_dir="$deps/cmake"
PY=${PYTHON:-python3}

say() { printf 'bootstrap: %s\n' "$*" >&2; }
die() { say "error: $*"; exit 1; }

command -v cargo >/dev/null 2>&1 || die "cargo not found: install Rust (rustup) first; rust-toolchain.toml pins the version"
command -v "$PY" >/dev/null 2>&1 || die "$PY not found: Python 3 with pip is needed to fetch libtorch and MuJoCo from PyPI"
"$PY" -m pip --version >/dev/null 2>&1 || die "'$PY -m pip' does not work: install pip (Debian: python3-pip)"
command -v cc >/dev/null 2>&1 || die "no C compiler (cc) found: install build-essential"

mkdir -p "$deps"

# --- libtorch -------------------------------------------------------------------------
stamp="$py_dir/.torch-$TORCH_VERSION.ok"
if [ ! -f "$stamp" ]; then
  say "installing torch==$TORCH_VERSION (libtorch, ~530 MB) and CUDA runtime stubs into $py_dir"
  "$PY" -m pip install --quiet --disable-pip-version-check --no-deps --no-compile \
    --target "$py_dir" --upgrade \
    "torch==$TORCH_VERSION" "nvidia-cuda-cupti==13.0.85.*" "nvidia-cuda-runtime==13.0.96.*"
  [ -f "$py_dir/torch/lib/libtorch_cpu.so" ] || die "torch wheel installed but $py_dir/torch/lib/libtorch_cpu.so is missing"
  touch "$stamp"
else
  say "libtorch $TORCH_VERSION already in $py_dir"
fi

# --- MuJoCo ---------------------------------------------------------------------------
if [ ! -f "$mj_dir/libmujoco.so.$MUJOCO_VERSION" ]; then
  say "fetching mujoco==$MUJOCO_VERSION's libmujoco.so into $mj_dir"
  tmp=$(mktemp -d)
  trap 'rm -rf "$tmp"' EXIT
  "$PY" -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: \
    -d "$tmp" "mujoco==$MUJOCO_VERSION"
  mkdir -p "$mj_dir"
  "$PY" - "$tmp" "$mj_dir" "$MUJOCO_VERSION" <<'PYEOF'
import glob, os, sys, zipfile
tmp, out, ver = sys.argv[1:]
wheels = glob.glob(os.path.join(tmp, "mujoco-*.whl"))
if not wheels:
    sys.exit(f"bootstrap: error: no mujoco wheel downloaded into {tmp}")
name = f"libmujoco.so.{ver}"
with zipfile.ZipFile(wheels[0]) as z:
    members = [m for m in z.namelist() if m.endswith("/" + name)]
    if not members:
        sys.exit(f"bootstrap: error: {wheels[0]} holds no {name}")
    with z.open(members[0]) as src, open(os.path.join(out, name + ".part"), "wb") as dst:
        dst.write(src.read())
os.replace(os.path.join(out, name + ".part"), os.path.join(out, name))
PYEOF
  ln -sf "libmujoco.so.$MUJOCO_VERSION" "$mj_dir/libmujoco.so"
else
  say "MuJoCo $MUJOCO_VERSION already in $mj_dir"
fi

# --- CMake (static HDF5 for the Minari import) --------------------------------------
if command -v cmake >/dev/null 2>&1; then
  say "cmake already on PATH ($(command -v cmake))"
elif [ ! -x "$cmake_dir/cmake/data/bin/cmake" ]; then
  say "installing cmake==$CMAKE_VERSION (PyPI wheel) into $cmake_dir"
  "$PY" -m pip install --quiet --disable-pip-version-check --no-deps --no-compile \
    --target "$cmake_dir" --upgrade "cmake==$CMAKE_VERSION"
  [ -x "$cmake_dir/cmake/data/bin/cmake" ] || die "cmake wheel installed but $cmake_dir/cmake/data/bin/cmake is missing"
else
  say "cmake already in $cmake_dir"
fi

# --- cargo-nextest (the test runner of `make test`) --------------------------------------
NEXTEST_VERSION=0.9.143
if [ "$with_nextest" = 1 ]; then
  if cargo nextest --version >/dev/null 2>&1; then
    say "cargo-nextest already installed"
  else
    say "installing cargo-nextest $NEXTEST_VERSION (cargo install, a few minutes)"
    cargo install --locked --quiet "cargo-nextest@$NEXTEST_VERSION"
  fi
  command -v openssl >/dev/null 2>&1 ||
    die "the TLS tests need the openssl command (Debian: apt-get install openssl)"
  # The dashboard test drives a real headless browser over WebDriver.
  if command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; then
    say "chromium and chromedriver already installed"
  else
    say "installing chromium and chromium-driver (apt; the dashboard test's browser)"
    sudo=""
    [ "$(id -u)" = 0 ] || sudo="sudo"
    $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \
      chromium chromium-driver >/dev/null ||
      die "could not install chromium and chromium-driver (Debian packages; root or sudo needed)"
  fi
  ORT_VERSION=1.23.2
  NUMPY_VERSION=2.3.5
  # TensorBoard's own event reader for the event-file test, with what it imports.
  TB_VERSION=2.21.0
  PB_VERSION=7.36.2
  ABSL_VERSION=2.5.1
  PACKAGING_VERSION=26.4
  # The upstream MCAP reader and Foxglove's schema classes for the run-log scene test.
  MCAP_VERSION=1.6.0
  FOXGLOVE_SCHEMAS_VERSION=0.4.0
  ZSTANDARD_VERSION=0.25.0
  LZ4_VERSION=4.4.5
  pytest_dir="$deps/pytest"
  stamp="$pytest_dir/.onnxruntime-$ORT_VERSION-numpy-$NUMPY_VERSION-tensorboard-$TB_VERSION-mcap-$MCAP_VERSION.ok"
  if [ ! -f "$stamp" ]; then
    say "installing onnxruntime==$ORT_VERSION, numpy==$NUMPY_VERSION tensorboard==$TB_VERSION and mcap==$MCAP_VERSION (the tests' outside readers) into $pytest_dir"
    rm -rf "$pytest_dir"
    "$PY" -m pip install --quiet --disable-pip-version-check --no-deps --no-compile \
      --target "$pytest_dir" "onnxruntime==$ORT_VERSION" "numpy==$NUMPY_VERSION" \
      "tensorboard==$TB_VERSION" "protobuf==$PB_VERSION" "absl-py==$ABSL_VERSION" \
      "packaging==$PACKAGING_VERSION" "mcap==$MCAP_VERSION" \
      "foxglove-schemas-protobuf==$FOXGLOVE_SCHEMAS_VERSION" \
      "zstandard==$ZSTANDARD_VERSION" "lz4==$LZ4_VERSION"
    PYTHONPATH="$pytest_dir" "$PY" -c "import onnxruntime" ||
      die "onnxruntime installed into $pytest_dir but does not import"
    PYTHONPATH="$pytest_dir" "$PY" -c "from tensorboard.backend.event_processing import event_accumulator" ||
      die "tensorboard installed into $pytest_dir but its event reader does not import"
    PYTHONPATH="$pytest_dir" "$PY" -c "import mcap.reader, foxglove_schemas_protobuf.SceneUpdate_pb2" ||
      die "mcap / foxglove-schemas-protobuf installed into $pytest_dir but do not import"
    touch "$stamp"
  else
    say "onnxruntime $ORT_VERSION and tensorboard $TB_VERSION already in $pytest_dir"
  fi
fi

# --- cargo-fuzz (coverage-guided fuzzing, `make fuzz`) ----------------------------------
CARGO_FUZZ_VERSION=0.13.2
if [ "$with_fuzz" = 1 ]; then
  rustup run nightly rustc --version >/dev/null 2>&1 ||
    die "make fuzz needs a nightly toolchain (rustup toolchain install nightly); make test does not"
  if cargo fuzz --version >/dev/null 2>&1; then
    say "cargo-fuzz already installed"
  else
    say "installing cargo-fuzz $CARGO_FUZZ_VERSION (cargo install, about a minute)"
    cargo +nightly install --locked --quiet "cargo-fuzz@$CARGO_FUZZ_VERSION"
  fi
fi

# --- env file -------------------------------------------------------------------------
torch_dir="$py_dir/torch"
cu_dir="$py_dir/nvidia/cu13/lib"
cat > "$deps/env.sh.part" <<ENVEOF
# Written by scripts/bootstrap.sh; source it before cargo.
export LIBTORCH="$torch_dir"
export LIBTORCH_CXX11_ABI=1
export MUJOCO_DYNAMIC_LINK_DIR="$mj_dir"
export LD_LIBRARY_PATH="$torch_dir/lib:$cu_dir:$mj_dir\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
export PATH="$cmake_dir/cmake/data/bin:\$PATH"
ENVEOF
mv "$deps/env.sh.part" "$deps/env.sh"
say "ready: source $deps/env.sh"
