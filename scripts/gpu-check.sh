#!/usr/bin/env bash
# GPU readiness in one command. On a machine with CUDA: builds, times the update on CPU and
# CUDA (the paper's sizes and walker-td3's), trains walker-td3 briefly on CUDA, and checks that
# a CPU and a CUDA update agree (crates/rdpg-agents/tests/cuda.rs, relative tolerance 1e-3).
# Without CUDA it says so and exits 0. Prints JSON lines; record them in BENCHMARKS.md.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
# shellcheck source=scripts/setup/deps.sh
source scripts/setup/deps.sh
if ! python3 -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)"; then
  echo "gpu-check: no CUDA device visible to torch on this machine: nothing to check"
  exit 0
fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
cargo build --release -p rdpg-cli
rdpg=target/release/rdpg
"$rdpg" train --help >/dev/null
for dev in cpu cuda; do
  "$rdpg" bench update --scan 24 --batch 64 --opt 8 --iters 20 --device "$dev"
done
out="$(mktemp -d)"
"$rdpg" train --quiet --config configs/walker-td3.toml --steps 20000 --set agent.device='"cuda"' \
  --set off_policy.warmup_steps=5000 --set train.eval_every=10000 --set train.test_episodes=5 \
  --out "$out/walker-td3-cuda"
cargo test --release -p rdpg-agents --test cuda -- --nocapture
rm -rf "$out"
echo "gpu-check: done"
