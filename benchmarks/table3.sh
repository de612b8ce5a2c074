#!/usr/bin/env bash
# Table III at scale from one command: the four teacher-free learned arms, recurrent PQN
# (`pqn`, GRU cells), its memoryless and frame-stacked twins (`pqn-dqn`, `pqn-stack`) and
# recurrent PPO (`ppo`), 5 seeds each at one env-step budget; every run's greedy agent is
# evaluated on the same 1,000 episodes beside the rule-based agent and its family's
# frontier (docs/spec.md §9). First the estimate (one timed training chunk per arm: the
# study's training wall time on this device), then the study. Its rows go into
# docs/results.json, section table3-<backend> (table3-gpu, table3-cpu), which
# `drqn-jax report README.md docs/results.md` quotes; its learning curves and safety/speed
# figure go into docs/figures/table3-<backend>-*.png. Running it again continues an
# interrupted study, in a fresh clone too, from the finished runs its runs store keeps
# (docs/finished-runs/table3-<backend>.json, removed once the study finishes).
#
# Budget per seed: TABLE3_STEPS env steps; by default 24,000,000 on an accelerator (the
# length of benchmarks/gpu.sh's learning curve, above the 20M floor of docs/spec.md) and
# 6,000,000 on a CPU, what 2 cores afford (section table3-cpu of docs/results.json keeps
# each arm's training time per seed).
#
# Usage, from the repository root of an installed clone:
#   benchmarks/table3.sh [OUT]                   # OUT defaults to runs/table3-<backend>
#   TABLE3_DRY_RUN=1 benchmarks/table3.sh [OUT]  # validate and describe; train nothing
#                                                # (the suite runs this)
#   TABLE3_ESTIMATE=0 benchmarks/table3.sh       # skip the estimate
# PYTHON names the interpreter (default python3).
set -euo pipefail
py=${PYTHON:-python3}
backend=$("$py" -c "import jax; print(jax.default_backend())")
if [ "$backend" = cpu ]; then default_steps=6000000; else default_steps=24000000; fi
steps=${TABLE3_STEPS:-$default_steps}
out=${1:-runs/table3-$backend}
export PYTHONUNBUFFERED=1

study=("$py" -m drqn_jax.cli study --configs pqn,pqn-dqn,pqn-stack,ppo --seeds 5
       --episodes 1000 --set "train.num_env_steps=$steps" --out "$out")
echo "Table III at scale on $backend: $steps env steps per seed, into $out"
if [ "${TABLE3_DRY_RUN:-0}" = 1 ]; then
  "${study[@]}" --dry-run
  exit 0
fi
if [ "${TABLE3_ESTIMATE:-1}" = 1 ]; then
  "${study[@]}" --estimate
fi
"${study[@]}" --results docs/results.json --section "table3-$backend" \
  --runs-store "docs/finished-runs/table3-$backend.json"
# The report's figures: the learning curves against env steps to the full budget and the
# safety/speed figure (the study draws both into OUT when every run has finished).
for figure in curves safety_speed; do
  if [ -f "$out/$figure.png" ]; then
    cp "$out/$figure.png" "docs/figures/table3-$backend-${figure//_/-}.png"
    echo "docs/figures/table3-$backend-${figure//_/-}.png"
  fi
done
