#!/usr/bin/env bash
# `ess experiment --slurm` against a real Slurm: starts a single-node cluster (Debian's
# slurm-wlm and munge, from `scripts/bootstrap.sh --slurm`) in a temporary directory,
# runs a grid through `sbatch --array`, checks the report, and stops the daemons.
#
#   sudo -E bash bench/slurm_grid.sh [SPEC]       # default: deploy/experiments/smoke.toml
#
# Needs root (munged and slurmd run as root here), `source .deps/env.sh` and a release
# build (`cargo build --release`). Nothing outside the temporary directory is touched:
# the daemons get their own config (SLURM_CONF), munge key and socket, state and spool
# directories and ports.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
spec=${1:-$root/deploy/experiments/smoke.toml}
ess=$root/target/release/ess
for c in munged slurmctld slurmd sbatch sinfo; do
  command -v "$c" >/dev/null || { echo "slurm_grid: $c not found: run scripts/bootstrap.sh --slurm" >&2; exit 2; }
done
[ -x "$ess" ] || { echo "slurm_grid: $ess missing: cargo build --release" >&2; exit 2; }
[ "$(id -u)" = 0 ] || { echo "slurm_grid: needs root (munged, slurmd)" >&2; exit 2; }

t=$(mktemp -d /tmp/ess-slurm.XXXXXX)
chmod 755 "$t"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  sleep 1
  for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null || true; done
  [ -n "${KEEP:-}" ] || rm -rf "$t"
}
trap cleanup EXIT

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
host=$(hostname -s)
cpus=$(nproc)
mem=$(awk '/MemTotal/ {print int($2/1024) - 1024}' /proc/meminfo)
mkdir -p "$t/munge" "$t/state" "$t/spool" "$t/log"
dd if=/dev/urandom of="$t/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$t/munge/munge.key"
chmod 700 "$t/munge"
munged --force --key-file="$t/munge/munge.key" --socket="$t/munge/munge.sock" \
  --pid-file="$t/munge/munged.pid" --log-file="$t/log/munged.log" --seed-file="$t/munge/seed"
pids+=("$(cat "$t/munge/munged.pid")")

cat > "$t/slurm.conf" <<EOF
ClusterName=ess-test
SlurmctldHost=$host
AuthType=auth/munge
AuthInfo=socket=$t/munge/munge.sock
CredType=cred/munge
SlurmUser=root
SlurmdUser=root
SlurmctldPort=$(free_port)
SlurmdPort=$(free_port)
StateSaveLocation=$t/state
SlurmdSpoolDir=$t/spool
SlurmctldPidFile=$t/slurmctld.pid
SlurmdPidFile=$t/slurmd.pid
SlurmctldLogFile=$t/log/slurmctld.log
SlurmdLogFile=$t/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF=$t/slurm.conf
slurmctld -D -i > "$t/log/slurmctld.out" 2>&1 & pids+=($!)
slurmd -D > "$t/log/slurmd.out" 2>&1 & pids+=($!)
for _ in $(seq 60); do
  sinfo -h -o '%T' 2>/dev/null | grep -q idle && break
  sleep 1
done
sinfo -h -o '%T' | grep -q idle || { echo "slurm_grid: the node did not come up" >&2; tail -5 "$t"/log/*.log >&2; exit 1; }
echo "slurm_grid: single-node Slurm $(sinfo -V | awk '{print $2}') up on $host ($cpus CPUs)"

out=$t/grid
start=$(date +%s)
"$ess" experiment "$spec" --slurm --cores 1 --out "$out"
echo "slurm_grid: grid took $(( $(date +%s) - start )) s"
cells=$("$ess" experiment "$spec" --list --out "$out" | wc -l)
finished=$("$ess" experiment "$spec" --list --out "$out" | grep -c ' finished$' || true)
grep -q "^$cells of $cells cells finished" "$out/report.md" \
  || { echo "slurm_grid: FAIL: $finished of $cells cells finished" >&2; ls "$out/slurm" >&2; exit 1; }
ls "$out"/slurm/*.out >/dev/null
echo "slurm_grid: OK: $cells of $cells cells ran as array tasks; report $out/report.md"
