#!/usr/bin/env bash
# Whole-training speed of RL Zoo's TD3 on BipedalWalker-v3, rdpg vs Stable-Baselines3, in one
# run: env steps/s after the 10k random warm-up steps, one update per step; 1 thread each, then
# both cores each (rdpg: `parallel_twins`; SB3: 2 PyTorch threads).
# Usage: scripts/bench/bench_td3_zoo.sh [STEPS]   (default 30000). Needs target/release/rdpg
# and stable-baselines3 2.9.2 in .venv (pip install stable-baselines3==2.9.2).
set -euo pipefail
cd "$(dirname "$0")/../.."
steps="${1:-30000}"
out="$(mktemp -d)"
rdpg() { # $1: label, $2: threads used, rest: extra `rdpg train` arguments
  local label="$1" threads="$2"
  shift 2
  target/release/rdpg train --quiet --config configs/walker-td3-zoo.toml --steps "$steps" \
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
rdpg rdpg 1
.venv/bin/python3 scripts/bench/sb3_td3.py --steps "$steps" --threads 1
# Both cores: rdpg's twin critics on two threads (bit-identical updates), PyTorch's two
# intra-op threads for SB3.
rdpg rdpg-parallel-twins 2 --set agent.parallel_twins=true
.venv/bin/python3 scripts/bench/sb3_td3.py --steps "$steps" --threads 2
rm -rf "$out"
