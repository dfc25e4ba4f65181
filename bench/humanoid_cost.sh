#!/usr/bin/env bash
# What a Humanoid iteration costs, split (rollout, D/Q, PPO) and in env steps/s, for
# every way a 2-core machine can run it: in-process actor (`--actors 0`) or 2 `ess-actor`
# processes, sync or overlap pipeline, fused or tch backend. The settings run in turn
# (round robin: every setting once per round, ROUNDS rounds after one warm-up round)
# so that the machine's drift falls on all of them alike; each figure is the median
# over the rounds.
#
#   source .deps/env.sh && ROUNDS=3 bench/humanoid_cost.sh ./target/release/ess
#
# Each run: `ess train --env humanoid --set run.iterations=$ITERS --set
# run.eval_every=0` on one dataset generated beforehand, with a 2-episode evaluation
# reference so that set-up is short; phases and env steps/s from its summary.json.
set -euo pipefail
ess=${1:?usage: humanoid_cost.sh ESS}
rounds=${ROUNDS:-3}
iters=${ITERS:-20}
root=$(cd "$(dirname "$0")" && pwd)/runs/humanoid-cost
mkdir -p "$root"
demos=$root/humanoid-demos.safetensors
[ -f "$demos" ] || "$ess" demos generate --env humanoid --out "$demos" >/dev/null
rows=$root/rows.jsonl
: >"$rows"

settings=(
  "fused|0|sync"
  "fused|0|overlap"
  "fused|2|sync"
  "fused|2|overlap"
  "tch|0|sync"
  "tch|0|overlap"
  "tch|2|sync"
  "tch|2|overlap"
)

for round in $(seq 0 "$rounds"); do # round 0 is the warm-up
  for s in "${settings[@]}"; do
    IFS='|' read -r backend actors pipeline <<<"$s"
    out=$root/$backend-$actors-$pipeline-$round
    rm -rf "$out"
    "$ess" train --env humanoid --backend "$backend" --actors "$actors" \
      --set run.pipeline="\"$pipeline\"" --set run.iterations="$iters" \
      --set run.eval_every=0 --set demos.path="\"$demos\"" \
      --set run.reference_episodes=2 --out "$out" >"$out.log" 2>&1
    python3 - "$out/summary.json" "$s" "$round" >>"$rows" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); p = s["seconds_per_iteration"]
print(json.dumps(dict(setting=sys.argv[2], round=int(sys.argv[3]), rollout=p["rollout"],
                      disc=p["disc"], ppo=p["ppo"], sps=s["env_steps_per_second"],
                      iter=s["wall_seconds"] / max(s["iterations"], 1))))
PY
  done
done

python3 - "$rows" <<'PY'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
order = []
for r in rows:
    if r["setting"] not in order:
        order.append(r["setting"])
print("| backend | actors | pipeline | rollout s | D/Q s | PPO s | wall s / iteration | env steps/s |")
print("|---|---|---|---|---|---|---|---|")
for key in order:
    got = [r for r in rows if r["setting"] == key and r["round"] > 0]
    med = lambda k: statistics.median(r[k] for r in got)
    backend, actors, pipeline = key.split("|")
    actors = "in-process" if actors == "0" else f"{actors} processes"
    print(f"| {backend} | {actors} | {pipeline} | {med('rollout'):.3f} | {med('disc'):.3f} | "
          f"{med('ppo'):.3f} | {med('iter'):.3f} | {med('sps'):.0f} |")
print(f"\nmedian of {len({r['round'] for r in rows}) - 1} rounds each")
PY
