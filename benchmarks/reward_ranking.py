"""Which driving does a reward prefer? Each agent of :data:`AGENTS` on the same evaluation
episodes under each reward of :data:`REWARDS`: its return beside its safety and speed.

Usage::

    python -m benchmarks.reward_ranking [--episodes 1000]
        [--results docs/results.json] [--section reward-ranking]

A learner maximizes the return, not the goal (docs/results.md): where a collision-free
agent at the paper's DRQN's speed earns less under a reward than a trained agent, no
learner of that reward can be expected to reach the goal. The reward changes the return
only, never the episodes or the actions, so each agent drives the same under every reward.
Margins are to the rule-based frontier stored for the world and episodes (SPEC §9), which the
section keeps.
"""

import json
import shlex
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import base_parser, report
from benchmarks.learning_curve import stored_frontier
from drqn_jax.cli import main as cli
from drqn_jax.config import load_config
from drqn_jax.env.params import KMH
from drqn_jax.experiments.baselines import frontier_key
from drqn_jax.experiments.frontier import with_margin
from drqn_jax.experiments.machine import machine_info
from drqn_jax.experiments.report import write_results
from drqn_jax.experiments.rows import baseline_row

#: label → ``drqn-jax evaluate`` arguments choosing the agent. The planner's cap stays under
#: the speed limit (a cap at it with a 1 km/h band overspeeds: r_v's penalty, SPEC §5) and
#: high enough that its average speed reaches the paper's DRQN's.
AGENTS = {
    "shipped pqn (Table III at scale, seed 0)": "--agent headline",
    "planner, cap 10 km/h": f"--agent planner --set planner.v_cap={10 * KMH}",
    "planner, cap 14.6 km/h, band 0.4 km/h": f"--agent planner --set planner.v_cap={14.6 * KMH}"
    f" --set planner.speed_band={0.4 * KMH}",
}
#: label → ``drqn-jax evaluate`` overrides of the reward (SPEC §5); the first is default's.
#: A tenth of r_nc is the paper's ratio of r_nc to a stand (docs/spec.md §5).
REWARDS = {"default's reward": "", "r_nc weight 0.1": "--set env.reward_near_collision_weight=0.1"}


def evaluated(arguments: Sequence[str], episodes: int) -> dict[str, Any]:
    """``drqn-jax evaluate ARGUMENTS --episodes EPISODES``'s JSON metrics."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "metrics.json"
        command = ["evaluate", *arguments, "--episodes", str(episodes), "--quiet"]
        if cli([*command, "--json", str(path)]) != 0:
            raise SystemExit(f"drqn-jax {shlex.join(command)} failed")
        return json.loads(path.read_text())


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = base_parser("reward_ranking", __doc__)
    parser.add_argument("--episodes", type=int, default=1000, help="evaluation episodes")
    parser.add_argument("--results", default="docs/results.json", help="the results file")
    parser.add_argument("--section", default="reward-ranking", help="its section")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes >= 1")
    config = load_config("default", [f"evaluate.episodes={args.episodes}"])
    frontier = stored_frontier(config, Path(args.results))
    if frontier is None:
        parser.error("no frontier of the world on these episodes in --results: drqn-jax frontier")
    start, rows = time.perf_counter(), []
    for reward, sets in REWARDS.items():
        for agent, arguments in AGENTS.items():
            result = evaluated(f"{arguments} {sets}".split(), args.episodes)
            row = baseline_row(f"{agent}; {reward}", result, world=config["env"]["id"])
            rows.append(with_margin(row, frontier, config.speed_limit_kmh()))
    command = shlex.join(["python", "-m", "benchmarks.reward_ranking", *(argv or sys.argv[1:])])
    about = {"command": command, "wall_time_s": time.perf_counter() - start}
    about.update(machine=machine_info(), frontiers={frontier_key(config): frontier})
    write_results(args.results, args.section, rows, [], about)
    lines = [
        f"* {r['label']}: {100 * r['collision_free_rate']:.1f} % collision-free at "
        f"{r['avg_speed_kmh']:.2f} km/h, return {r['avg_return']:.1f}"
        for r in rows
    ]
    title = "Which driving a reward prefers"
    return report("reward_ranking", title, {"rows": rows}, lines, args.out, argv)


if __name__ == "__main__":
    main()
