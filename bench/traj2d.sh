#!/usr/bin/env bash
# Table 1, 2D-trajectory column: all seven presets x SEEDS seeds with the same budget,
# two runs at a time with one libtorch thread each (2-core machine), then one timing
# run alone with the default libtorch threads. One in-process actor thread (--actors 0),
# the default when the table was made. Writes bench/traj2d.md.
#   ITERS=300 SEEDS="0 1 2 3 4" JOBS=2 bash bench/traj2d.sh
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ITERS=${ITERS:-300}
SEEDS=${SEEDS:-"0 1 2 3 4"}
JOBS=${JOBS:-2}
PRESETS=${PRESETS:-"gail infogail acgail elastic-infogail ess-infogail-no-gs ess-infogail-no-rim ess-infogail"}
OUT=${OUT:-bench/runs/traj2d}
ESS=./target/release/ess
mkdir -p "$OUT"
jobs_list=()
for p in $PRESETS; do for s in $SEEDS; do jobs_list+=("$p $s"); done; done
run_one() {
  local p=$1 s=$2 dir="$OUT/$1-s$2"
  if [ -f "$dir/summary.json" ]; then return 0; fi
  "$ESS" train --preset "$p" --seed "$s" --out "$dir" --actors 0 \
    --set run.iterations="$ITERS" --set run.torch_threads=1 --set run.eval_every=50 \
    > "$dir.log" 2>&1 || { echo "FAILED: $p seed $s (see $dir.log)" >&2; return 1; }
  echo "done: $p seed $s $(grep -E '^NMI' "$dir.log" | head -1)"
}
export -f run_one; export OUT ITERS ESS
printf '%s\n' "${jobs_list[@]}" | xargs -P "$JOBS" -n 2 bash -c 'run_one "$0" "$1"'
# Timing alone on the machine, default threads, the paper's per-iteration settings.
"$ESS" train --seed 0 --out "$OUT/timing" --actors 0 --set run.iterations=30 --set run.eval_every=0 \
  > "$OUT/timing.log" 2>&1
python3 bench/aggregate_traj2d.py "$OUT" "$ITERS" "$SEEDS" > bench/traj2d.md
cat bench/traj2d.md
