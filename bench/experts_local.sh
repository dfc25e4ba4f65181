#!/usr/bin/env bash
# Trains every shipped expert one after another on one core (the budget used for the
# files in deploy/experts; see bench/mujoco.md). Args: env:steps pairs.
set -euo pipefail
BIN=${BIN:-./target/release/ess}
DIR=${DIR:-deploy/experts}
# One in-process actor thread: the default when the shipped experts were trained.
PPO="--set ppo.epochs=10 --set ppo.minibatch=250 --set run.torch_threads=1"
PPO="$PPO --set run.actors=1 --set run.transport=\"threads\""
for spec in "$@"; do
  IFS=: read -r env steps <<<"$spec"
  n=$("$BIN" train --env "$env" --print-config | awk '/^n_modes/ {print $3; exit}')
  for ((k = 0; k < n; k++)); do
    "$BIN" experts train --env "$env" --mode "$k" --steps "$steps" --seed "$k" \
      --out "$DIR/$env/mode$k.safetensors" $PPO 2>&1 | tail -n 2
  done
done
