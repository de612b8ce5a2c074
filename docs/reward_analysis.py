"""Which driver does the paper's reward prefer? A table for docs/notebook/yielding-world.md.

Two scripted drivers on the same 1000 evaluation episodes of a config: the
rule-based agent (brakes for any pedestrian on the road within 7 m of its
corridor: never collides here) and the same agent that never brakes
(``rule_based.lookahead = 0``: it holds 15 km/h whatever is ahead), under
the paper's reward and under a larger collision penalty and a smaller
penalty for standing still. A learner maximising the return is pulled
towards whichever driver earns more::

    python docs/reward_analysis.py [--config default] [--episodes 1000]
"""

from __future__ import annotations

import argparse
import itertools
import time

from drqn_jax.config import load_config
from drqn_jax.experiments.runner import builtin_agent, evaluate_agents

#: (env.reward_collision, env.reward_stopped): the paper's, then the alternatives.
REWARDS = ((-10.0, -1.0), (-100.0, -1.0), (-10.0, -0.1), (-100.0, -0.1))
DRIVERS = (("rule-based (brakes within 7 m)", 7.0), ("never brakes", 0.0))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="default", help="config name or TOML path")
    parser.add_argument("--episodes", type=int, default=1000, help="evaluation episodes")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rows = [
        "| r_c (collision) | stopped reward | driver | collision-free % | avg speed (km/h) "
        "| return per episode |",
        "| ---: | ---: | --- | ---: | ---: | ---: |",
    ]
    for (collision, stopped), (driver, lookahead) in itertools.product(REWARDS, DRIVERS):
        config = load_config(
            args.config,
            [
                f"env.reward_collision={collision}",
                f"env.reward_stopped={stopped}",
                f"rule_based.lookahead={lookahead}",
                f"evaluate.episodes={args.episodes}",
            ],
        )
        (r,) = evaluate_agents(config, [builtin_agent("rule-based", config)])
        rows.append(
            f"| {collision:g} | {stopped:g} | {driver} | {100 * r['collision_free_rate']:.1f} "
            f"| {r['avg_speed_kmh']:.2f} | {r['avg_return']:.1f} |"
        )
    print("\n".join(rows))
    print(
        f"\n{args.config}, {args.episodes} episodes per row (evaluation key of run.seed), "
        f"{time.perf_counter() - start:.0f} s"
    )


if __name__ == "__main__":
    main()
