#!/usr/bin/env bash
# The cost of a remote actor host (`ess actor-host`, `[remote]`) against a local actor:
# the same run twice, two actor processes each, on the same machine: (a) both local;
# (b) one local and one on a host in its own network namespace (veth pair, made here and
# removed after), over zenoh with mutual TLS (certificates made with openssl). Prints the
# bytes that crossed the veth per iteration (its kernel counters), and the per-iteration
# rollout and total times from each run's metrics.csv.
#
#   sudo -E bash bench/remote.sh [ENV] [ITERATIONS]     # default: reacher 6
#
# Needs root (network namespaces), `source .deps/env.sh` and a release build.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
env=${1:-reacher}
iters=${2:-6}
ess=$root/target/release/ess
[ -x "$ess" ] || { echo "remote: $ess missing: cargo build --release" >&2; exit 2; }
[ "$(id -u)" = 0 ] || { echo "remote: needs root (network namespaces)" >&2; exit 2; }

t=$(mktemp -d /tmp/ess-remote.XXXXXX)
ns=essbench$$; va=eb$$a; vb=eb$$b
host_pid=
cleanup() {
  [ -n "$host_pid" ] && kill "$host_pid" 2>/dev/null || true
  ip link del "$va" 2>/dev/null || true
  ip netns del "$ns" 2>/dev/null || true
  [ -n "${KEEP:-}" ] || rm -rf "$t"
}
trap cleanup EXIT

ip netns add "$ns"
ip link add "$va" type veth peer name "$vb"
ip link set "$vb" netns "$ns"
ip addr add 10.99.1.1/24 dev "$va"; ip link set "$va" up
ip netns exec "$ns" ip addr add 10.99.1.2/24 dev "$vb"
ip netns exec "$ns" ip link set "$vb" up
ip netns exec "$ns" ip link set lo up

cd "$t"
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -keyout ca.key \
  -out ca.pem -subj "/CN=bench ca" -days 2 2>/dev/null
for pair in learner:serverAuth host:clientAuth; do
  n=${pair%%:*}
  printf 'subjectAltName=IP:10.99.1.1\nextendedKeyUsage=%s\nbasicConstraints=CA:FALSE\n' "${pair##*:}" > "$n.ext"
  openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -keyout "$n.key" \
    -out "$n.csr" -subj "/CN=$n" 2>/dev/null
  openssl x509 -req -in "$n.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -out "$n.pem" \
    -days 2 -extfile "$n.ext" 2>/dev/null
done
cat > remote.toml <<TOML
[remote]
listen = "tls/10.99.1.1:17450"
hosts = ["bench"]
tls_ca = "$t/ca.pem"
tls_cert = "$t/learner.pem"
tls_key = "$t/learner.key"
TOML

train() { # OUT ARGS...
  local out=$1; shift
  RUST_LOG=warn "$ess" train --env "$env" --seed 0 --out "$out" \
    --set run.iterations="$iters" --set run.eval_every=1000 --set run.eval_episodes=1 \
    --set run.reference_episodes=1 --set run.torch_threads=1 "$@" >/dev/null
}
# Mean of a metrics.csv column over iterations 2.. (the first pays start-up).
col() { python3 - "$1" "$2" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1] + "/metrics.csv")))[1:]
print(f"{sum(float(r[sys.argv[2]]) for r in rows) / len(rows):.4f}")
PY
}

train local --actors 2
rx0=$(cat /sys/class/net/$va/statistics/rx_bytes); tx0=$(cat /sys/class/net/$va/statistics/tx_bytes)
ip netns exec "$ns" "$ess" actor-host --once --learner tls/10.99.1.1:17450 --name bench --actors 1 \
  --tls-ca ca.pem --tls-cert host.pem --tls-key host.key 2>host.log &
host_pid=$!
train remote --actors 1 --config remote.toml
wait "$host_pid" || { echo "remote: the host failed:"; cat host.log; exit 1; }
host_pid=
rx1=$(cat /sys/class/net/$va/statistics/rx_bytes); tx1=$(cat /sys/class/net/$va/statistics/tx_bytes)

steps=$(python3 -c "import csv; r=list(csv.DictReader(open('remote/metrics.csv'))); print(int(r[0]['env_steps']))")
echo "env $env, $iters iterations of $steps steps, 2 actor processes; machine: $(nproc) cores"
echo "wire (veth, whole remote run incl. start-up): learner->host $(( (tx1 - tx0) / iters )) B/iteration, host->learner $(( (rx1 - rx0) / iters )) B/iteration"
for run in local remote; do
  echo "$run: rollout_s $(col $run rollout_s)  wall_s/iteration $(python3 - $run <<'PY'
import csv, sys
r = list(csv.DictReader(open(sys.argv[1] + "/metrics.csv")))
print(f"{(float(r[-1]['wall_s']) - float(r[0]['wall_s'])) / (len(r) - 1):.4f}")
PY
)"
done
for k in nmi ent normalized_reward; do
  echo "$k: local $(python3 -c "import json; print(json.load(open('local/summary.json'))['$k'])") remote $(python3 -c "import json; print(json.load(open('remote/summary.json'))['$k'])")"
done
