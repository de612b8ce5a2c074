#!/usr/bin/env bash
# The learners' GPU figures from one command:
#   1. the learning throughput of every learner (benchmarks/train_throughput.py): the
#      replay DRQN at its own 32 envs, PQN and PPO at 4,096 envs, one seed each
#      (OUT/throughput/); PQN with 5 seeds vmapped in one program (OUT/seeds/);
#   2. PQN's learning curve (benchmarks/learning_curve.py): one seed of the `pqn` preset
#      trained to 24M env steps, its greedy agent evaluated on 1,000 episodes at 12
#      marks: collision-free rate, speed and margin against env steps (OUT/curve/).
# Each writes its JSON and Markdown under OUT (default runs/gpu).
#
# Usage, from the repository root of an installed clone:
#   benchmarks/gpu.sh [OUT]
#   GPU_DRY_RUN=1 benchmarks/gpu.sh OUT   # tiny sizes on any device: the suite runs this
# PYTHON names the interpreter (default python3).
set -euo pipefail
out=${1:-runs/gpu}
py=${PYTHON:-python3}
mkdir -p "$out"
export PYTHONUNBUFFERED=1

if [ "${GPU_DRY_RUN:-0}" = 1 ]; then
  throughput=(--quick --learners pqn)
  seeds=(--quick --learners pqn --seeds 2)
  curve=(--config smoke --set train.algorithm=pqn --set train.rollout_steps=8
         --set train.num_minibatches=1 --set train.chunk_iterations=1
         --set train.num_env_steps=96
         --set train.num_episodes=64 --points 2 --episodes 4)
else
  throughput=(--learners default pqn ppo --envs 4096)
  seeds=(--learners pqn --envs 4096 --seeds 5)
  curve=(--config pqn --set train.num_env_steps=24000000 --points 12 --episodes 1000)
fi

"$py" -c "import jax; print('JAX', jax.__version__, jax.devices())"
start=$SECONDS
"$py" -m benchmarks.train_throughput "${throughput[@]}" --out "$out/throughput"
"$py" -m benchmarks.train_throughput "${seeds[@]}" --out "$out/seeds"
echo "throughput: $((SECONDS - start)) s"
start=$SECONDS
"$py" -m benchmarks.learning_curve "${curve[@]}" --out "$out/curve"
echo "learning curve: $((SECONDS - start)) s"
