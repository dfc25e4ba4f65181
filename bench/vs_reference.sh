#!/usr/bin/env bash
# Ess against the paper's PyTorch code (../shared/reference, set up with its setup.sh and
# collect_demos.sh) on Reacher at the paper's settings, run alternately on one machine:
# a warm-up pair, then PAIRS pairs (reference, Ess, reference, Ess, ...), the ratio of
# env steps per second taken pair by pair and the median quoted.
#
#   REF_DIR=/path/with/Ess-InfoGAIL bench/vs_reference.sh ESS [PAIRS] [extra ess args...]
#   REF_DIR=... bench/vs_reference.sh ./target/release/ess 3                     # default actors
#   REF_DIR=... bench/vs_reference.sh ./target/release/ess 3 --actors 0 --set run.torch_threads=1
#
# Reference: `run_ref.sh $REF_ITERS` (default 6; one torch thread), its mean over
# iterations 2..K. Ess: `ess train --env reacher` for $ITERS iterations (default 30)
# without periodic evaluation, on a dataset generated once, env steps/s from its
# summary.json (training only, set-up excluded, as on the reference side).
set -euo pipefail
ess=${1:?usage: vs_reference.sh ESS [PAIRS] [extra ess args...]}
pairs=${2:-3}
shift $(( $# >= 2 ? 2 : 1 ))
ref=${REF_DIR:?set REF_DIR (see ../shared/reference/README.md)}
iters=${ITERS:-30}
root=$(cd "$(dirname "$0")" && pwd)/runs/vs-reference
mkdir -p "$root"
demos=$root/reacher-demos.safetensors
[ -f "$demos" ] || "$ess" demos generate --env reacher --out "$demos" >/dev/null
rows=$root/rows.jsonl
: > "$rows"
for i in $(seq 0 "$pairs"); do # pair 0 is the warm-up
  "$ref/run_ref.sh" "${REF_ITERS:-6}" > "$root/ref-$i.log" 2>&1
  ref_sps=$(grep -a '^\[ref\] mean over' "$root/ref-$i.log" | sed -E 's/.* ([0-9.]+) env steps\/s.*/\1/')
  out=$root/ess-$i
  rm -rf "$out"
  "$ess" train --env reacher --set run.iterations="$iters" --set run.eval_every=0 \
    --set demos.path="\"$demos\"" --set run.reference_episodes=2 --out "$out" "$@" > "$out.log" 2>&1
  python3 - "$out/summary.json" "$i" "$ref_sps" >> "$rows" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); p = s["seconds_per_iteration"]
print(json.dumps(dict(pair=int(sys.argv[2]), ref=float(sys.argv[3]), ess=s["env_steps_per_second"],
                      rollout=p["rollout"], disc=p["disc"], ppo=p["ppo"])))
PY
done
python3 - "$rows" <<'PY'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if json.loads(l)["pair"] > 0]
print("| pair | reference env steps/s | Ess env steps/s | Ess rollout / D/Q / PPO s per iteration | ratio |")
print("|---|---|---|---|---|")
for r in rows:
    print(f"| {r['pair']} | {r['ref']:.0f} | {r['ess']:.0f} | {r['rollout']:.3f} / {r['disc']:.3f} / {r['ppo']:.3f} | {r['ess'] / r['ref']:.1f}x |")
print(f"\nmedian of pairwise ratios: {statistics.median(r['ess'] / r['ref'] for r in rows):.1f}x")
PY
