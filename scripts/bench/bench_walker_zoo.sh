#!/usr/bin/env bash
# Whole-training speed on BipedalWalker-v3 at RL Zoo's sizes, rdpg vs Stable-Baselines3, in one
# run: env steps/s after the 10k random warm-up steps, one update per step. `td3`
# (configs/walker-td3-zoo.toml): 1 thread each, then both cores each (rdpg: `parallel_twins`;
# SB3: 2 PyTorch threads). `sac` (configs/walker-sac.toml) and `tqc` (configs/walker-tqc.toml,
# against sb3-contrib's TQC): 1 thread each, then SB3 on 2.
# Usage: scripts/bench/bench_walker_zoo.sh td3|sac|tqc [STEPS]   (default 30000). Needs
# target/release/rdpg and stable-baselines3 2.9.2 in .venv (pip install stable-baselines3==2.9.2;
# for tqc also sb3-contrib==2.9.2).
set -euo pipefail
cd "$(dirname "$0")/../.."
algo="$1"
steps="${2:-30000}"
config=configs/walker-td3-zoo.toml
[ "$algo" = sac ] && config=configs/walker-sac.toml
[ "$algo" = tqc ] && config=configs/walker-tqc.toml
out="$(mktemp -d)"
rdpg() { # $1: label, $2: threads used, rest: extra `rdpg train` arguments
  local label="$1" threads="$2"
  shift 2
  target/release/rdpg train --quiet --config "$config" --steps "$steps" \
    --set train.eval_every=0 --set train.test_episodes=1 "$@" --out "$out/$label" >/dev/null
  .venv/bin/python3 - "$out/$label/metrics.jsonl" "$steps" "$label" "$threads" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if '"episode"' in l]
warm = next(r for r in rows if r["step"] >= 10_000)
last = rows[-1]
sps = (last["step"] - warm["step"]) / (last["wall"] - warm["wall"])
ms = [r["learner"]["update_ms"] for r in rows if r["learner"].get("update_ms")]
print(json.dumps({"impl": sys.argv[3], "threads": int(sys.argv[4]), "steps": int(sys.argv[2]),
                  "warmup_steps": 10000, "steps_per_sec_after_warmup": round(sps, 1),
                  "update_ms_mean": round(sum(ms) / len(ms), 3)}))
PY
}
rdpg "rdpg-$algo" 1
.venv/bin/python3 scripts/bench/sb3_walker.py --algo "$algo" --steps "$steps" --threads 1
# Both cores: rdpg's twin critics on two threads (bit-identical updates; TD3 only), PyTorch's
# two intra-op threads for SB3.
if [ "$algo" = td3 ]; then
  rdpg rdpg-td3-parallel-twins 2 --set agent.parallel_twins=true
fi
.venv/bin/python3 scripts/bench/sb3_walker.py --algo "$algo" --steps "$steps" --threads 2
rm -rf "$out"
