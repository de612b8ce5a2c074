#!/usr/bin/env bash
# Table III at scale from one command, every arm teacher-free, 5 seeds each at one budget of
# ticks, each run's greedy agent evaluated on the same 1,000 episodes beside the rule-based
# agent and its family's frontier (docs/spec.md §9; the yardstick decides every tick).
#   TABLE3_GROUP=paper (default): recurrent PQN (`pqn`, GRU cells), its memoryless and
#     frame-stacked twins (`pqn-dqn`, `pqn-stack`) and recurrent PPO (`ppo`) in the paper's
#     world; section table3-<backend>-k<K> of docs/results.json.
#   TABLE3_GROUP=occluded: `pqn`, `pqn-dqn` and `pqn-stack` in UrbanPedestriansOccluded-v0,
#     where a memory has something to make up for; section table3-<backend>-k<K>-occluded.
# Each learner decides every TABLE3_K ticks of 0.1 s (env.decision_steps, default 5:
# docs/results.md section 5) and trains on TABLE3_TICKS ticks per seed (default 20,000,000,
# the floor of docs/spec.md; 50,000,000 on an accelerator), TABLE3_TICKS / TABLE3_K
# decisions (train.num_env_steps). First the estimate (one timed training chunk per arm),
# then the study; `drqn-jax report README.md docs/results.md` quotes its rows, and its
# figures go into docs/figures/<section>-*.png. Running it again continues an interrupted
# study, in a fresh clone too, from the finished runs its runs store keeps
# (docs/finished-runs/<section>.json, removed once the study finishes).
#
# Usage, from the repository root of an installed clone:
#   benchmarks/table3.sh [OUT]                   # OUT defaults to runs/<section>
#   TABLE3_DRY_RUN=1 benchmarks/table3.sh [OUT]  # validate and describe; train nothing
#                                                # (the suite runs this)
#   TABLE3_ESTIMATE=0 benchmarks/table3.sh       # skip the estimate
# PYTHON names the interpreter (default python3).
set -euo pipefail
py=${PYTHON:-python3}
backend=$("$py" -c "import jax; print(jax.default_backend())")
if [ "$backend" = cpu ]; then default_ticks=20000000; else default_ticks=50000000; fi
ticks=${TABLE3_TICKS:-$default_ticks}
k=${TABLE3_K:-5}
case ${TABLE3_GROUP:-paper} in
  paper) configs=pqn,pqn-dqn,pqn-stack,ppo; world=(); section=table3-$backend-k$k ;;
  occluded) configs=pqn,pqn-dqn,pqn-stack
            world=(--set env.id=UrbanPedestriansOccluded-v0)
            section=table3-$backend-k$k-occluded ;;
  *) echo "TABLE3_GROUP must be paper or occluded" >&2; exit 2 ;;
esac
out=${1:-runs/$section}
export PYTHONUNBUFFERED=1

study=("$py" -m drqn_jax.cli study --configs "$configs" --seeds 5 --episodes 1000
       "${world[@]}" --set "env.decision_steps=$k" --set "train.num_env_steps=$((ticks / k))"
       --out "$out")
echo "Table III at scale on $backend ($section): $ticks ticks per seed, a decision every $k, into $out"
if [ "${TABLE3_DRY_RUN:-0}" = 1 ]; then
  "${study[@]}" --dry-run
  exit 0
fi
if [ "${TABLE3_ESTIMATE:-1}" = 1 ]; then
  "${study[@]}" --estimate
fi
"${study[@]}" --results docs/results.json --section "$section" \
  --runs-store "docs/finished-runs/$section.json"
# The report's figures: the learning curves and the safety/speed figure (the study draws
# both into OUT when every run has finished).
for figure in curves safety_speed; do
  if [ -f "$out/$figure.png" ]; then
    cp "$out/$figure.png" "docs/figures/$section-${figure//_/-}.png"
    echo "docs/figures/$section-${figure//_/-}.png"
  fi
done
