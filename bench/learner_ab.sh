#!/usr/bin/env bash
# A/B of two `ess` builds (or two settings) on a task (ENV, default reacher) with the paper's settings, run
# alternately (warm-up pair, then A B A B ...), the ratio taken pair by pair and the
# median quoted: machines here drift by 2x within minutes, so only paired ratios hold.
#
#   bench/learner_ab.sh A_ESS B_ESS [PAIRS]            # two binaries, same settings
#   A_ARGS="--set run.pipeline=\"overlap\"" bench/learner_ab.sh ess ess
#   ENV=humanoid A_ARGS="--backend fused" B_ARGS="--backend tch" bench/learner_ab.sh ess ess 3
#
# Each run: `ess train --env $ENV --set run.iterations=$ITERS --set run.eval_every=0`
# on one dataset generated beforehand (`ess demos generate`) with a 2-episode
# evaluation reference, so that set-up is short; its per-iteration phase seconds and
# end-to-end env steps/s come from its summary.json. Extra arguments for both sides go
# in ARGS, for one side in A_ARGS / B_ARGS. Needs `source .deps/env.sh`; each binary
# needs its `ess-actor` beside it.
set -euo pipefail
a_bin=${1:?usage: learner_ab.sh A_ESS B_ESS [PAIRS]}
b_bin=${2:?usage: learner_ab.sh A_ESS B_ESS [PAIRS]}
pairs=${3:-5}
iters=${ITERS:-30}
env=${ENV:-reacher}
root=$(cd "$(dirname "$0")" && pwd)/runs/learner-ab
mkdir -p "$root"
demos=$root/$env-demos.safetensors
[ -f "$demos" ] || "$a_bin" demos generate --env "$env" --out "$demos" >/dev/null
rows=$root/rows.jsonl
: > "$rows"

one() { # side binary index extra-args
  local side=$1 bin=$2 i=$3 extra=$4 out="$root/$1-$3"
  # shellcheck disable=SC2086
  "$bin" train --env "$env" --set run.iterations="$iters" --set run.eval_every=0 \
    --set demos.path="\"$demos\"" --set run.reference_episodes=2 --out "$out" \
    ${ARGS:-} $extra >"$out.log" 2>&1
  python3 - "$out/summary.json" "$side" "$i" >>"$rows" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); p = s["seconds_per_iteration"]
print(json.dumps(dict(side=sys.argv[2], pair=int(sys.argv[3]), rollout=p["rollout"],
                      disc=p["disc"], ppo=p["ppo"], sps=s["env_steps_per_second"],
                      iter=s["wall_seconds"] / max(s["iterations"], 1))))
PY
}

for i in $(seq 0 "$pairs"); do # pair 0 is the warm-up
  one a "$a_bin" "$i" "${A_ARGS:-}"
  one b "$b_bin" "$i" "${B_ARGS:-}"
done

python3 - "$rows" <<'PY'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
get = lambda side: {r["pair"]: r for r in rows if r["side"] == side and r["pair"] > 0}
a, b = get("a"), get("b")
print("| pair | A D/Q s | A PPO s | A env steps/s | B D/Q s | B PPO s | B env steps/s | update A/B | env steps/s A/B |")
print("|---|---|---|---|---|---|---|---|---|")
ratios = {"update": [], "disc": [], "ppo": [], "sps": []}
for i in sorted(a):
    x, y = a[i], b[i]
    upd = (x["disc"] + x["ppo"]) / (y["disc"] + y["ppo"])
    ratios["update"].append(upd)
    ratios["disc"].append(x["disc"] / y["disc"])
    ratios["ppo"].append(x["ppo"] / y["ppo"])
    ratios["sps"].append(x["sps"] / y["sps"])
    print(f"| {i} | {x['disc']:.3f} | {x['ppo']:.3f} | {x['sps']:.0f} | {y['disc']:.3f} | "
          f"{y['ppo']:.3f} | {y['sps']:.0f} | {upd:.3f} | {x['sps'] / y['sps']:.3f} |")
med = {k: statistics.median(v) for k, v in ratios.items()}
print(f"\nmedian of pairwise ratios A/B: update (D/Q + PPO) {med['update']:.3f} "
      f"(D/Q {med['disc']:.3f}, PPO {med['ppo']:.3f}); end-to-end env steps/s {med['sps']:.3f}")
print("median rollout s/iteration: A %.3f, B %.3f" % (
    statistics.median(x["rollout"] for x in a.values()),
    statistics.median(y["rollout"] for y in b.values())))
print("median wall s/iteration: A %.3f, B %.3f; iteration / update: A %.3f, B %.3f" % (
    statistics.median(x["iter"] for x in a.values()),
    statistics.median(y["iter"] for y in b.values()),
    statistics.median(x["iter"] / (x["disc"] + x["ppo"]) for x in a.values()),
    statistics.median(y["iter"] / (y["disc"] + y["ppo"]) for y in b.values())))
PY
