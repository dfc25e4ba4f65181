#!/usr/bin/env bash
# Import speed and peak memory of `ess demos import` on a 1M-transition arm3 dataset,
# recorded by tests/fixtures/arm3/record.py with the upstream minari + gymnasium (and
# written again as .npz by numpy). Needs a Python with mujoco==3.17.0 gymnasium
# "minari[create,hdf5]" pillow numpy: PY=/path/to/venv/bin/python.
#   PY=... bash bench/custom_import.sh [WORKDIR]
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
work=${1:-$root/bench/runs/custom-import}
PY=${PY:-python3}
ess=$root/target/release/ess
task=task:$root/deploy/tasks/arm3/task.toml
mkdir -p "$work"
# 9756 + 9756 + 488 episodes of 50 steps = 1,000,000 transitions (imbalance 20).
if [ ! -f "$work/arm3-1m.npz" ]; then
  "$PY" "$root/tests/fixtures/arm3/record.py" --out "$work/minari" --npz "$work/arm3-1m.npz" \
    --episodes 9756 9756 488 --seed 1
fi
du -sb "$work/minari/ess/arm3-v0/data/main_data.hdf5" "$work/arm3-1m.npz"
for src in "$work/minari/ess/arm3-v0" "$work/arm3-1m.npz"; do
  extra=()
  [[ $src == *.npz ]] || extra=(--labels-field infos/mode)
  /usr/bin/time -f "wall %e s, peak RSS %M KB" "$ess" demos import "$src" --env "$task" \
    "${extra[@]}" --label-ratio 0.02 --out "$work/out.safetensors" --force > /dev/null
done
du -sb "$work/out.safetensors"
