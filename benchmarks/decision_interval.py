"""The study of the decision interval (``env.decision_steps = k``): one seed per config
and k at one budget of ticks, greedy curves against ticks and CPU seconds.

Usage::

    python -m benchmarks.decision_interval [--configs pqn,pqn-dqn] [--k 1,2,5,10]
        [--ticks 6000000] [--points 4] [--episodes 1000] [--seed 0]
        [--results docs/results.json] [--section decision-interval]

Each arm is one run of a config at ``env.decision_steps = k`` trained on
``train.num_env_steps = ticks // k`` decisions (a decision cut short by a collision or
the goal plays fewer ticks), its greedy agent evaluated on the same ``--episodes``
evaluation episodes at ``--points`` evenly spaced marks
(:func:`drqn_jax.experiments.curves.greedy_curve`). The last mark is the trained agent:
its row, with its margin over the rule-based frontier stored for the world (the
yardstick decides every tick: SPEC §9), goes to ``--results`` as section ``--section``
with every arm's curve. Arms already there are not trained again, so the same command
continues an interrupted study, on this machine or another clone.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import base_parser, markdown_table, report
from benchmarks.learning_curve import stored_frontier
from drqn_jax.config import Config, load_config
from drqn_jax.experiments.baselines import frontier_key
from drqn_jax.experiments.curves import greedy_curve
from drqn_jax.experiments.frontier import with_margin
from drqn_jax.experiments.machine import machine_info
from drqn_jax.experiments.report import load_results, margin_cell, write_results
from drqn_jax.experiments.rows import study_row
from drqn_jax.experiments.verdicts import frontier_comparison
from drqn_jax.learners.hyperparams import agent_name, teacher_label

COLUMNS = {
    "label": "arm",
    "decision_steps": "k",
    "ticks": "ticks",
    "train_s": "training s",
    "collision_free": "collision-free %",
    "avg_speed_kmh": "avg speed (km/h)",
    "margin": "margin (pts)",
}


def arm_label(name: str, k: int, sets: Sequence[str] = ()) -> str:
    """The row label of config ``name`` at ``k`` ticks per decision with overrides ``sets``."""
    return ", ".join([f"drqn_jax: {name}", f"k = {k}", *sets])


def arm(name: str, k: int, args: argparse.Namespace) -> tuple[str, Config]:
    """The label and config of ``name`` (with ``--set``) at ``k`` ticks per decision,
    trained on ``--ticks // k`` decisions."""
    sets = [
        *args.set,
        f"env.decision_steps={k}",
        f"train.num_env_steps={args.ticks // k}",
        f"evaluate.episodes={args.episodes}",
        f"run.seed={args.seed}",
    ]
    return arm_label(name, k, args.set), load_config(name, sets)


def arm_row(label: str, config: Config, point: dict[str, Any], frontier: Any) -> dict[str, Any]:
    """The results row ``label`` of an arm's last curve point (its trained agent)."""
    k = config["env"]["decision_steps"]
    teacher = teacher_label(config.hyperparams())
    run = {**point, "train_wall_s": point["train_s"], "teacher": teacher}
    row = study_row(label, agent_name(config.train_config()), [run], world=config["env"]["id"])
    row.update(decision_steps=k, ticks_per_seed=k * point["env_steps"])
    return with_margin(row, frontier, config.speed_limit_kmh())


def _stored(results: str, section: str) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    record = load_results(results)
    rows = [r for r in record["rows"] if r.get("section") == section]
    return rows, record["sections"].get(section, {})


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = base_parser("decision_interval", __doc__)
    parser.add_argument("--configs", default="pqn,pqn-dqn", help="comma-separated configs")
    parser.add_argument("--k", default="1,2,5,10", help="ticks per decision, comma-separated")
    parser.add_argument("--ticks", type=int, default=6_000_000, help="ticks of training per arm")
    parser.add_argument("--points", type=int, default=4, help="evaluations per arm")
    parser.add_argument("--episodes", type=int, default=1000, help="episodes per evaluation")
    parser.add_argument("--seed", type=int, default=0, help="run.seed of every arm")
    parser.add_argument("--results", default="docs/results.json", help="the results file")
    parser.add_argument("--section", default="decision-interval", help="its section")
    parser.add_argument(
        "--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override"
    )
    args = parser.parse_args(argv)
    names = [n for n in args.configs.split(",") if n]
    ks = [int(k) for k in args.k.split(",") if k]
    if min(ks) < 1 or args.ticks < max(ks) or args.points < 1 or args.episodes < 1:
        parser.error("--k >= 1, --ticks >= the largest k, --points and --episodes >= 1")
    arms = [arm(n, k, args) for n in names for k in ks]
    frontier = stored_frontier(arms[0][1], Path(args.results))
    if frontier is None or any(frontier_key(c) != frontier_key(arms[0][1]) for _, c in arms):
        parser.error("the arms need one world and episodes with a frontier in --results")
    rows, about = _stored(args.results, args.section)
    curves = dict(about.get("curves", {}))
    earlier_s, start = about.get("wall_time_s", 0.0), time.perf_counter()
    command = shlex.join(["python", "-m", "benchmarks.decision_interval", *(argv or sys.argv[1:])])
    commands = [c for c in about.get("command", "").splitlines() if c != command] + [command]
    for label, config in arms:
        if any(r["label"] == label for r in rows):
            continue
        k = config["env"]["decision_steps"]
        print(f"{label}: {config['train']['num_env_steps']:,} decisions", flush=True)
        status, points = greedy_curve(config, args.points, args.episodes)
        if status != "finished":
            parser.exit(130, f"{label}: {status}; the finished arms are stored\n")
        for p in points:
            p["ticks"] = k * p["env_steps"]
        rows.append(arm_row(label, config, points[-1], frontier))
        curves[label] = points
        write_results(
            args.results,
            args.section,
            rows,
            [frontier_comparison(r) for r in rows],
            {
                "command": "\n".join(commands),
                "wall_time_s": earlier_s + time.perf_counter() - start,
                "continued": True,
                "machine": machine_info(),
                "frontiers": {frontier_key(config): frontier},
                "curves": curves,
            },
        )
    table = [
        {
            **r,
            "ticks": r["ticks_per_seed"],
            "train_s": r["train_wall_s_per_seed"],
            "collision_free": f"{100 * r['collision_free_rate']:.1f}",
            "margin": margin_cell(r),
        }
        for r in rows
    ]
    result = {"section": args.section, "rows": rows, "curves": curves}
    lines = [f"Section `{args.section}` of {args.results}.", "", *markdown_table(table, COLUMNS)]
    return report("decision_interval", "The decision interval", result, lines, args.out, argv)


if __name__ == "__main__":
    main()
