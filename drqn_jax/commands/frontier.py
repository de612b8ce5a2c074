"""``drqn-jax frontier``: the rule-based and planner frontiers (SPEC §9)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from drqn_jax.commands import (
    check_section_option,
    default_run_dir,
    episodes_text,
    evaluation_overrides,
    say,
)
from drqn_jax.config import Config, ConfigError, load_config
from drqn_jax.env.params import KMH
from drqn_jax.experiments.checkpoint import atomic_write_text
from drqn_jax.experiments.runner import EXIT_OK


def cmd_frontier(args: argparse.Namespace) -> int:
    """The rule-based family's safety/speed frontier and the privileged planner's
    ceiling (SPEC §9) on a config's evaluation episodes

    Sweep the rule-based agent's parameters (v_max up to the speed limit, lookahead,
    horizon, corridor margin) as one compiled program and keep the Pareto-efficient points
    (collision-free rate against average speed): the frontier every agent's margin is
    measured against. Then play the privileged planner at each speed cap. Writes
    OUT/frontier.json (every swept point) and OUT/frontier.png.
    """
    from drqn_jax.experiments.baselines import config_frontier
    from drqn_jax.experiments.frontier import WIDE_GRID, grid_settings

    overrides = evaluation_overrides(args.overrides, args.episodes, args.seed)
    config = load_config(args.config, overrides)
    try:
        caps = [float(c) for c in args.caps.split(",") if c.strip()]
    except ValueError:
        raise ConfigError(f"--caps {args.caps!r}: must be numbers (km/h), e.g. 5,10,15") from None
    if args.check < 0:
        raise ConfigError(f"--check {args.check}: must be an integer >= 0")
    if args.results:
        check_section_option(args.section)
    settings = grid_settings(WIDE_GRID) if args.wide else None
    if not args.quiet:
        say(
            f"sweeping {len(settings) if settings else 'the default'} rule-based settings"
            + ("" if args.no_planner else f" and the planner at {len(caps)} caps")
            + f" on {episodes_text(config)}..."
        )
    start = time.perf_counter()
    try:
        record = config_frontier(
            config, planner=not args.no_planner, settings=settings, caps_kmh=caps, keep_all=True
        )
    except ValueError as err:
        raise ConfigError(str(err)) from None
    checks = [_reviewer_check(config, record, args.check)] if args.check else []
    wall = time.perf_counter() - start
    _frontier_outputs(args, config, record, checks, wall)
    return EXIT_OK


def _frontier_outputs(
    args: argparse.Namespace, config: Config, record: dict[str, Any], checks: list[str], wall: float
) -> None:
    """OUT/frontier.json and .png, the --results section, and the table on stdout."""
    from drqn_jax.experiments.baselines import frontier_key
    from drqn_jax.experiments.report import study_table
    from drqn_jax.experiments.rows import frontier_rows, paper_rows

    rows = paper_rows() + frontier_rows(record, record["speed_limit_kmh"])
    out = Path(args.out or default_run_dir("frontier", args.config))
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "frontier.json", json.dumps(record, indent=1) + "\n")
    if not args.no_png:
        from drqn_jax.experiments.curves import plot_safety_speed

        plot_safety_speed(rows, record, out / "frontier.png")
    times = {
        f"{kind}_wall_time_s": record[kind]["wall_time_s"]
        for kind in ("rule_based", "planner")
        if kind in record
    }
    if args.results:
        from drqn_jax.experiments.machine import machine_info
        from drqn_jax.experiments.report import write_results

        rule = {k: v for k, v in record["rule_based"].items() if k != "swept_points"}
        about = {"command": args.command_line, "wall_time_s": wall, **times}
        about |= {
            "machine": machine_info(),
            "frontiers": {frontier_key(config): {**record, "rule_based": rule}},
        }
        write_results(args.results, args.section, rows, checks, about)
    print(study_table(rows, checks))
    print(
        f"\n{record['rule_based']['swept']} rule-based settings"
        + (f" and {len(record['planner']['points'])} planner caps" if "planner" in record else "")
        + f" on {record['episodes']} episodes of {record['world']}: "
        + ", ".join(f"{k.removesuffix('_wall_time_s')} {v:.1f} s" for k, v in times.items())
        + f"; {wall:.1f} s in all\nwritten to {out}"
    )


def _reviewer_check(config: Config, record: dict[str, Any], n: int) -> str:
    """``n`` random rule-based settings on ``record``'s episodes against its frontier."""
    from drqn_jax.experiments.baselines import config_frontier
    from drqn_jax.experiments.frontier import frontier_vertices, random_settings, reviewer_check

    seed = config["run"]["seed"]
    limit = config["env"]["v_ref"] / KMH
    tried = config_frontier(
        config, planner=False, settings=random_settings(n, seed, limit), keep_all=True
    )
    vertices = frontier_vertices(record["rule_based"]["points"])
    return reviewer_check(tried["rule_based"]["swept_points"], vertices, seed)
