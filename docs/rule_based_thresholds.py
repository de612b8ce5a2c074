"""The rule-based agent (SPEC §6) over its two thresholds (docs/notebook/yielding-world.md §9).

Evaluates it on the same 1000 episodes for every corridor margin and look-ahead
given, on the paper's and the realistic pedestrians, and prints a Markdown
table (a few seconds per cell on a 2-core CPU)::

    python docs/rule_based_thresholds.py --margins 0.5,0.3,0.1 --lookaheads 7,5,4,3
    python docs/rule_based_thresholds.py --envs UrbanPedestriansHeedless-v0   # §10
    python docs/rule_based_thresholds.py --v-maxes 14 --margins 0.5,0.4 --lookaheads 7,5,4
    python docs/rule_based_thresholds.py --v-maxes 14.5 --margins 0.45 --lookaheads 5 --horizons 0,1
"""

from __future__ import annotations

import argparse
import itertools

import jax

import drqn_jax
from drqn_jax.agents import rule_based_agent
from drqn_jax.agents.rule_based import RuleBasedParams
from drqn_jax.env.params import KMH

ENVS = ("UrbanPedestrians-v0", "UrbanPedestriansRealistic-v0")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--margins", default="0.5,0.3,0.1", help="corridor margins (m)")
    parser.add_argument("--lookaheads", default="7,5,4,3", help="look-aheads (m)")
    parser.add_argument("--v-maxes", default="15", help="speeds it tracks (km/h)")
    parser.add_argument("--horizons", default="0", help="anticipation horizons (s)")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=7, help="key of the episodes")
    parser.add_argument("--envs", default=",".join(ENVS), help="comma-separated env ids")
    args = parser.parse_args(argv)
    env_ids = args.envs.split(",")
    envs = [drqn_jax.make(env_id) for env_id in env_ids]
    key = jax.random.key(args.seed)
    axes = (args.v_maxes, args.margins, args.lookaheads, args.horizons)
    head = "| v_max (km/h) | corridor margin (m) | look-ahead (m) | horizon (s) | "
    print(head + " | ".join(env_ids) + " |")
    print("| ---: | ---: | ---: | ---: |" + " --- |" * len(env_ids))
    for v_max, margin, lookahead, horizon in itertools.product(
        *(map(float, a.split(",")) for a in axes)
    ):
        rb = RuleBasedParams(
            v_max=v_max * KMH, corridor_margin=margin, lookahead=lookahead, horizon=horizon
        )
        agent = rule_based_agent(rb)
        cells = []
        for env, params in envs:
            r = drqn_jax.evaluate(agent, key, args.episodes, env, params)
            cells.append(f"{100 * r['collision_free_rate']:.1f} %, {r['avg_speed_kmh']:.2f} km/h")
        row = f"| {v_max:g} | {margin} | {lookahead} | {horizon:g} | "
        print(row + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
