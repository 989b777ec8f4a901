#!/usr/bin/env bash
# The README's main job. First, within seconds, a trained walker from the zoo: its
# deterministic evaluation on 5 test seeds (stock reward) and report/zoo-walker-td3.gif. Then a
# short real training run of RDPG and DDPG on BipedalWalker-v3 (stock reward, the paper's
# networks) that ends by writing a report into report/:
#   report/curves.png          learning curves (training return, deterministic evaluations)
#   report/comparison.md       the Table-I-shaped comparison (named rewards and metrics)
#   report/walker-rdpg.gif     the trained RDPG walker on a held-out seed
#   report/runs/walker-*/      the run directories (metrics, checkpoints, resolved configs)
# About a minute on a 2-core machine (RESULTS.md, "The README's main command"): far too short to learn to walk (see RESULTS.md for longer
# runs); STEPS=N changes the budget. Needs target/release/rdpg (scripts/setup.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
steps="${STEPS:-6000}"
out=report
rm -rf "$out/runs"
mkdir -p "$out"
echo "== zoo/walker-td3: a trained walker (zoo/walker-td3/summary.json has its 100-episode test)"
target/release/rdpg eval --run zoo/walker-td3 --episodes 5
target/release/rdpg render --run zoo/walker-td3 --seed 3000000 --max-steps 1000 \
    --gif "$out/zoo-walker-td3.gif" --scale-down 2 --every 4
echo "== a short training run (RDPG vs DDPG, $steps steps each)"
for algo in rdpg ddpg; do
    target/release/rdpg train --config "configs/walker-$algo.toml" --steps "$steps" \
        --set off_policy.warmup_steps=1000 --set off_policy.updates_per_step=0.1 \
        --set train.eval_every=2000 --set train.eval_episodes=3 --set train.test_episodes=20 \
        --out "$out/runs/walker-$algo"
done
target/release/rdpg compare "$out/runs/walker-rdpg" "$out/runs/walker-ddpg" \
    --out "$out/comparison.md" --plot "$out/curves.png"
target/release/rdpg render --run "$out/runs/walker-rdpg" --seed 1000000 \
    --gif "$out/walker-rdpg.gif" --scale-down 2 --every 4
echo "report: $out/zoo-walker-td3.gif $out/comparison.md $out/curves.png $out/walker-rdpg.gif"
