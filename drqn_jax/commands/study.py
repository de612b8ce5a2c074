"""``drqn-jax study`` (Table III over configs × seeds), ``report`` and ``frontier`` (SPEC §9)."""

import argparse
import functools
import json
import time
from pathlib import Path
from typing import Any

from drqn_jax.commands import default_run_dir, episodes_text, evaluation_overrides, say
from drqn_jax.config import Config, ConfigError, load_config
from drqn_jax.experiments.checkpoint import atomic_write_text
from drqn_jax.experiments.report import check_section
from drqn_jax.experiments.runner import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK


def cmd_study(args: argparse.Namespace) -> int:
    """Configs x seeds trained and evaluated on the same episodes, beside the
    rule-based agent: Table III with intervals, and training curves

    Train every config for seeds 0 … N-1 (a sweep in OUT/<config>/, its agents in
    OUT/<config>/agents/run-NNNN), evaluate every run and the rule-based agent on the first
    seed's evaluation episodes, and write OUT/study.md (the paper's Table III beside ours,
    with 95 % intervals across seeds), OUT/study.json and the training curves as
    OUT/curves.png and OUT/curves.rrd. Ctrl-C saves checkpoints (status 130); the same
    command continues the study, with a larger --seeds adds seeds, and --eval-envs on a
    finished study only evaluates.
    """
    from drqn_jax.experiments.study import plan_study, run_study

    configs = [c.strip() for c in args.configs.split(",") if c.strip()]
    if args.smooth < 1:
        raise ConfigError(f"--smooth {args.smooth}: must be an integer >= 1")
    eval_envs = [e.strip() for e in args.eval_envs.split(",") if e.strip()]
    arms = plan_study(configs, args.seeds, args.episodes, args.overrides, eval_envs)
    out = Path(args.out or Path("runs") / f"study-{'-'.join(a.name for a in arms)}")
    section = args.section or out.name
    if args.results:
        check_section(section)
    store = Path(args.runs_store) if args.runs_store else None
    if store is None and args.results:  # the default store beside the results file
        store = Path(args.results).parent / "finished-runs" / f"{section}.json"
    for arm in arms:
        say(f"{arm.name}: {arm.sweep.describe()}")
    if args.estimate:
        from drqn_jax.commands.bench import estimate_lines

        print(
            estimate_lines(
                [(a.name, a.config, len(a.sweep.points), a.sweep.strategy) for a in arms]
            )
        )
    if args.estimate or args.dry_run:
        return EXIT_OK
    start = time.perf_counter()
    # each finished run outlives --out, even if the machine goes away
    keep = None if store is None else functools.partial(_keep, args, section, store)
    kept = store is not None and store.is_file()  # finished runs of an earlier invocation
    outcome = run_study(
        arms,
        out,
        smooth=args.smooth,
        png=not args.no_png,
        quiet=args.quiet,
        train=not args.report_only,
        carried=json.loads(store.read_text())["finished_runs"] if kept else None,
        keep=keep,
    )
    if outcome.status == "interrupted":
        say(f"interrupted; checkpoints saved, continue with the same command (--out {out})")
        if keep is not None and outcome.finished_runs:
            keep(outcome.finished_runs)
            count = sum(len(r) for r in outcome.finished_runs.values())
            say(
                f"{count} finished run(s) kept in {store}: the same command continues "
                "from them in a fresh --out"
            )
        return EXIT_INTERRUPTED
    wall = time.perf_counter() - start
    if args.results:
        _store_rows(args, section, out, outcome, wall)
    if store is not None and not args.report_only:  # every run is in the rows now
        store.unlink(missing_ok=True)
    print(outcome.table)
    print(f"\nwall time {wall:.1f} s; study in {out}")
    return EXIT_OK


def _keep(
    args: argparse.Namespace, section: str, store: Path, finished: dict[str, list[dict]]
) -> None:
    """Keep the ``finished`` runs in ``store``; with ``--results`` mark the section in progress."""
    from drqn_jax.experiments.report import note_progress

    store.parent.mkdir(parents=True, exist_ok=True)
    record = {"command": args.command_line, "finished_runs": finished}
    atomic_write_text(store, json.dumps(record, indent=1) + "\n")
    if args.results:
        counts = {arm: len(runs) for arm, runs in finished.items()}
        note_progress(args.results, section, counts, args.command_line, str(store))


def _store_rows(
    args: argparse.Namespace, section: str, out: Path, outcome: Any, wall: float
) -> None:
    """The finished study as ``section`` of ``--results``, with its safety/speed figure."""
    from drqn_jax.experiments.machine import machine_info
    from drqn_jax.experiments.report import load_results, write_results

    about = {
        "command": args.command_line,
        "wall_time_s": wall,
        "continued": outcome.continued,
        "machine": machine_info(),
    }
    earlier = load_results(args.results)["sections"].get(section)
    # The runs' provenance stays the command that trained them; an earlier report's command
    # is replaced, since this report may hold arms that one did not.
    if args.report_only and earlier and "--report-only" not in earlier["command"].split():
        about = {**earlier, "report_command": args.command_line}
    about["frontiers"] = outcome.frontiers
    write_results(args.results, section, outcome.rows, outcome.comparisons, about)
    say(f"rows stored as section {section!r} of {args.results}")
    if not args.no_png and (out / "safety_speed.png").is_file():
        figure = Path(args.results).parent / "figures" / f"{section}-safety-speed.png"
        figure.parent.mkdir(parents=True, exist_ok=True)
        figure.write_bytes((out / "safety_speed.png").read_bytes())
        say(f"safety/speed figure: {figure}")


def cmd_report(args: argparse.Namespace) -> int:
    """Fill the results blocks of documents from the results file a study wrote

    Regenerate every block between '<!-- results:NAME -->' and '<!-- /results -->' in
    the documents from section NAME of the results file (drqn-jax study --results FILE
    --section NAME writes it): its table, comparisons, command and wall time, so that no
    document retypes a number.
    """
    from drqn_jax.experiments.report import load_results, update_document

    if not Path(args.results).is_file():
        raise ConfigError(f"--results {args.results}: no such file (a study writes it)")
    record = load_results(args.results)
    missing = [d for d in args.documents if not Path(d).is_file()]
    if missing:
        raise ConfigError(f"{missing[0]}: no such document")
    texts = {doc: Path(doc).read_text() for doc in args.documents}
    try:
        filled = {doc: update_document(text, record) for doc, text in texts.items()}
    except ValueError as err:
        raise ConfigError(str(err)) from None
    stale = [doc for doc, text in texts.items() if filled[doc] != text]
    if args.check:
        for doc in stale:
            say(f"{doc}: its results blocks differ from {args.results}")
        return EXIT_FAILED if stale else EXIT_OK
    for doc in stale:
        atomic_write_text(Path(doc), filled[doc])
        if not args.quiet:
            say(f"updated {doc}")
    return EXIT_OK


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
        check_section(args.section)
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
    settings = random_settings(n, seed, config.speed_limit_kmh())
    tried = config_frontier(config, planner=False, settings=settings, keep_all=True)
    vertices = frontier_vertices(record["rule_based"]["points"])
    return reviewer_check(tried["rule_based"]["swept_points"], vertices, seed)
