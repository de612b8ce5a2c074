"""The study of the decision interval (``env.decision_steps = k``): one seed per config
and k at one budget of ticks, greedy curves against ticks and CPU seconds.

Usage::

    python -m benchmarks.decision_interval [--configs pqn,pqn-dqn] [--k 1,2,5,10]
        [--ticks 6000000] [--points 4] [--episodes 1000] [--seeds 0]
        [--results docs/results.json] [--section decision-interval]

Each arm is one run of a config at ``env.decision_steps = k`` trained on
``train.num_env_steps = ticks // k`` decisions (a decision cut short by a collision or
the goal plays fewer ticks), its greedy agent evaluated on the same ``--episodes``
evaluation episodes at ``--points`` evenly spaced marks
(:func:`benchmarks.learning_curve.greedy_curve`), once per seed of ``--seeds``. The
last mark of each seed is its trained agent: the arm's row over its stored seeds, with
its margin over the rule-based frontier stored for the world (the yardstick decides
every tick: SPEC §9), goes to ``--results`` as section ``--section`` with every seed's
curve. Seeds already there are not trained again, so the same command continues an
interrupted study, and a later one with more seeds confirms an arm, on this machine or
another clone.
"""

import argparse
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import base_parser, markdown_table, report
from benchmarks.learning_curve import greedy_curve, stored_frontier
from drqn_jax.config import Config, load_config
from drqn_jax.experiments.baselines import frontier_key
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


def arm(name: str, k: int, seed: int, args: argparse.Namespace) -> tuple[str, Config]:
    """The label and config of ``name`` (with ``--set``) at ``k`` ticks per decision and
    ``run.seed = seed``, trained on ``--ticks // k`` decisions."""
    sets = [
        *args.set,
        f"env.decision_steps={k}",
        f"train.num_env_steps={args.ticks // k}",
        f"evaluate.episodes={args.episodes}",
        f"run.seed={seed}",
    ]
    return arm_label(name, k, args.set), load_config(name, sets)


def curve_key(label: str, seed: int) -> str:
    """The key of one seed's curve of arm ``label`` in the section's ``curves``."""
    return f"{label}, seed {seed}"


def arm_row(
    label: str, config: Config, curves: dict[str, list[dict[str, Any]]], frontier: Any
) -> dict[str, Any]:
    """The results row ``label`` over the last curve point (the trained agent) of every
    seed stored for the arm."""
    k = config["env"]["decision_steps"]
    teacher = teacher_label(config.hyperparams())
    seeds = {
        int(key.rsplit(" ", 1)[1]): points[-1]
        for key, points in curves.items()
        if key.rsplit(", seed ", 1)[0] == label
    }
    runs = [
        {**last, "train_wall_s": last["train_s"], "teacher": teacher, "values": {"run.seed": s}}
        for s, last in sorted(seeds.items())
    ]
    agent = agent_name(config.train_config())
    row = study_row(label, agent, runs, world=config["env"]["id"], decision_steps=k)
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
    parser.add_argument("--seeds", default="0", help="run.seed values, comma-separated")
    parser.add_argument("--results", default="docs/results.json", help="the results file")
    parser.add_argument("--section", default="decision-interval", help="its section")
    parser.add_argument(
        "--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override"
    )
    args = parser.parse_args(argv)
    names = [n for n in args.configs.split(",") if n]
    ks = [int(k) for k in args.k.split(",") if k]
    seeds = [int(s) for s in args.seeds.split(",") if s]
    if min(ks) < 1 or args.ticks < max(ks) or args.points < 1 or args.episodes < 1:
        parser.error("--k >= 1, --ticks >= the largest k, --points and --episodes >= 1")
    if not seeds or min(seeds) < 0:
        parser.error("--seeds: one or more integers >= 0")
    arms = [(arm(n, k, s, args), s) for n in names for k in ks for s in seeds]
    # every seed is judged on the frontier of the configs' own run.seed's episodes, as in a study
    base_seed = load_config(names[0], args.set)["run"]["seed"]
    bases = [arm(n, k, base_seed, args)[1] for n in names for k in ks]
    frontier, key = stored_frontier(bases[0], Path(args.results)), frontier_key(bases[0])
    if frontier is None or any(frontier_key(c) != key for c in bases):
        parser.error("the arms need one world and episodes with a frontier in --results")
    rows, about = _stored(args.results, args.section)
    curves = dict(about.get("curves", {}))
    start = time.perf_counter()
    command = shlex.join(["python", "-m", "benchmarks.decision_interval", *(argv or sys.argv[1:])])
    commands = [c for c in about.get("command", "").splitlines() if c != command] + [command]
    for (label, config), seed in arms:
        if curve_key(label, seed) in curves:
            continue
        k = config["env"]["decision_steps"]
        decisions = config["train"]["num_env_steps"]
        print(f"{label}, seed {seed}: {decisions:,} decisions", flush=True)
        status, points = greedy_curve(config, args.points, args.episodes)
        if status != "finished":
            parser.exit(130, f"{label}: {status}; the finished seeds are stored\n")
        for p in points:
            p["ticks"] = k * p["env_steps"]
        curves[curve_key(label, seed)] = points
        row = arm_row(label, config, curves, frontier)
        stored = [r["label"] for r in rows]
        if label in stored:
            rows[stored.index(label)] = row
        else:
            rows.append(row)
        write_results(
            args.results,
            args.section,
            rows,
            [frontier_comparison(r) for r in rows],
            {
                "command": "\n".join(commands),
                "wall_time_s": time.perf_counter() - start,  # this invocation's, as a study records
                "continued": True,
                "machine": machine_info(),
                "frontiers": {**about.get("frontiers", {}), key: frontier},
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
