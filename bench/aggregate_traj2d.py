#!/usr/bin/env python3
"""Aggregates bench/traj2d.sh runs into the markdown table of bench/traj2d.md."""
import json, os, platform, statistics, subprocess, sys, datetime

out, iters, seeds = sys.argv[1], int(sys.argv[2]), sys.argv[3].split()
presets = ["gail", "infogail", "acgail", "elastic-infogail",
           "ess-infogail-no-gs", "ess-infogail-no-rim", "ess-infogail"]
paper = {"gail": (0.392, 0.529), "infogail": (0.742, 0.371), "acgail": (0.783, 0.324),
         "elastic-infogail": (0.773, 0.330), "ess-infogail-no-gs": (0.892, 0.157),
         "ess-infogail-no-rim": (0.893, 0.159), "ess-infogail": (0.910, 0.131)}

def ms(xs):
    if not xs:
        return "n/a"
    sd = statistics.stdev(xs) if len(xs) > 1 else 0.0
    return f"{statistics.mean(xs):.3f} ± {sd:.3f}"

cpu = "unknown"
try:
    for line in open("/proc/cpuinfo"):
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip(); break
except OSError:
    pass
commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
print("# Traj2D: Table 1 (2D-trajectory column)\n")
print(f"Measured {datetime.date.today()} on {os.cpu_count()} cores ({cpu}), commit {commit}.")
print(f"Budget per run: {iters} iterations x 5000 env steps = {iters * 5000:,} steps; seeds {' '.join(seeds)};")
print("two runs at a time, one libtorch thread each. Final evaluation: 50 deterministic")
print("episodes per latent code, every step classified by the behaviour classifier.\n")
print(f"Command: `ITERS={iters} SEEDS=\"{' '.join(seeds)}\" bash bench/traj2d.sh` (after `make build`).\n")
print("| method | NMI (ours) | ENT (ours) | normalized reward | NMI (paper) | ENT (paper) | seeds |")
print("|---|---|---|---|---|---|---|")
for p in presets:
    rows = []
    for s in seeds:
        f = os.path.join(out, f"{p}-s{s}", "summary.json")
        if os.path.exists(f):
            rows.append(json.load(open(f)))
    nmi = [r["nmi"] for r in rows]; ent = [r["ent"] for r in rows]
    nr = [r["normalized_reward"] for r in rows]
    pn, pe = paper[p]
    print(f"| {p} | {ms(nmi)} | {ms(ent)} | {ms(nr)} | {pn:.3f} | {pe:.3f} | {len(rows)} |")
t = os.path.join(out, "timing", "summary.json")
if os.path.exists(t):
    s = json.load(open(t))
    sp = s["seconds_per_iteration"]
    print("\n## Speed (baseline for later speed-ups)\n")
    print("One ess-infogail run alone on the machine, default threads (libtorch uses both cores),")
    print("the paper's per-iteration settings: rollout 5000 steps, 50 D/Q steps of batch 1000,")
    print("20 PPO epochs (minibatch 1000), 1 actor thread.\n")
    print(f"Command: `ess train --seed 0 --set run.iterations=30 --set run.eval_every=0`\n")
    print("| phase | seconds / iteration |")
    print("|---|---|")
    print(f"| rollout (env + pure-Rust policy) | {sp['rollout']:.3f} |")
    print(f"| D/Q updates | {sp['disc']:.3f} |")
    print(f"| reward + GAE + PPO | {sp['ppo']:.3f} |")
    total = sp['rollout'] + sp['disc'] + sp['ppo']
    print(f"| total | {total:.3f} |")
    print(f"\nEnd to end: **{s['env_steps_per_second']:.0f} env steps/s** "
          f"({s['env_steps']} steps in {s['wall_seconds']:.1f} s).")
notes = os.path.join(os.path.dirname(os.path.abspath(__file__)), "traj2d-notes.md")
if os.path.exists(notes):
    print(open(notes).read(), end="")
