"""The README's agent table: rule-based, random and always-accelerate agents (SPEC §8).

Usage::

    python benchmarks/agent_table.py [--episodes 1000] [--seed 0] [--env UrbanPedestrians-v0]

Prints ``drqn_jax.evaluation.metrics_table`` of ``drqn_jax.evaluate`` for each
agent, with the evaluation key, the wall time and the machine.
"""

from __future__ import annotations

import argparse
import time

import jax

import drqn_jax
from drqn_jax.evaluation import metrics_table
from drqn_jax.experiments.machine import machine_info, machine_lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--episodes", type=int, default=1000, help="episodes per agent (default 1000)"
    )
    parser.add_argument("--seed", type=int, default=0, help="evaluation key seed (default 0)")
    parser.add_argument(
        "--env", default="UrbanPedestrians-v0", help="env id (default UrbanPedestrians-v0)"
    )
    args = parser.parse_args()

    env, params = drqn_jax.make(args.env)
    agents = [
        drqn_jax.rule_based_agent(),
        drqn_jax.random_agent(),
        drqn_jax.constant_agent("accelerate"),
    ]
    key = jax.random.key(args.seed)
    results = []
    start = time.perf_counter()
    for agent in agents:
        results.append(drqn_jax.evaluate(agent, key, args.episodes, env, params))
    wall = time.perf_counter() - start
    print(f"env {args.env}, {args.episodes} episodes per agent, key jax.random.key({args.seed})")
    print()
    print(metrics_table(results))
    print()
    print(f"wall time {wall:.1f} s, compile included")
    print("\n".join(machine_lines(machine_info())))


if __name__ == "__main__":
    main()
