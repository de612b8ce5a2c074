"""The ``drqn-jax`` command line: ``train``, ``evaluate``, ``reproduce``, ``replay``,
``sweep``, ``study``, ``frontier``, ``report``, ``bench``.

``replay`` records greedy episodes of a trained run or a built-in agent as a
rerun ``.rrd`` file (:mod:`drqn_jax.interop.recording`); ``train --rrd`` and
``reproduce --rrd`` write the training curves as one.

Exit statuses: 0 done; 1 the run failed (non-finite loss: the last good
checkpoint is kept); 2 a configuration, usage or checkpoint problem (one
line on stderr naming it); 130 interrupted by SIGINT/SIGTERM after saving a
checkpoint.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import shlex
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from drqn_jax import __version__
from drqn_jax.agents import drqn_agent
from drqn_jax.config import Config, ConfigError, config_names, load_config
from drqn_jax.env.params import KMH
from drqn_jax.evaluation import metrics_table
from drqn_jax.experiments.checkpoint import CheckpointError, atomic_write_text
from drqn_jax.experiments.frontier import PLANNER_CAPS_KMH
from drqn_jax.experiments.report import check_section
from drqn_jax.experiments.runner import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    builtin_agent,
    evaluate_agents,
    json_ready,
    load_run,
    load_trained_network,
    recorded_metrics,
    train_run,
    write_evaluation,
)
from drqn_jax.experiments.sweep import STRATEGIES
from drqn_jax.learners.hyperparams import agent_name
from drqn_jax.learners.selection import selection

__all__ = ["main"]


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Help with each option's default, once: not where the help text names it already,
    nor for defaults that say nothing (None, False, an empty list)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        silent = action.default in (None, False, [], argparse.SUPPRESS)
        if "(default:" in text or silent or not action.option_strings:
            return text
        return text + " (default: %(default)s)"


def _config_options(parser: argparse.ArgumentParser, default: str) -> None:
    parser.add_argument(
        "--config",
        default=default,
        help=f"TOML file, or a name in configs/ ({', '.join(config_names())})",
    )
    _set_option(parser, "override one field (repeatable), e.g. --set train.learning_rate=3e-4")


def _set_option(parser: argparse.ArgumentParser, help_text: str) -> None:
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        help=help_text,
    )


def _run_dir_option(parser: argparse.ArgumentParser, prefix: str) -> None:
    parser.add_argument(
        "--run-dir",
        default=None,
        help=f"where to write the run (default: runs/{prefix}-<config>-<UTC time>)",
    )


def _agent_options(parser: argparse.ArgumentParser, verb: str) -> None:
    """``[RUN_DIR]`` and ``--agent``: a trained run's DRQN or a built-in agent."""
    parser.add_argument(
        "run_dir",
        nargs="?",
        default=None,
        help="a run directory (its DRQN agent), or a sweep's trained agent: OUT/agents/run-NNNN",
    )
    parser.add_argument(
        "--agent",
        choices=_AGENTS,
        default=None,
        help=f"agent to {verb}; drqn: the run's trained agent, whatever its learner; planner: "
        "the privileged planner, which sees the true state and plays the simulator forward "
        "(a ceiling, not a learner; [planner] of the config) "
        "(default: drqn with RUN_DIR, rule-based without)",
    )


def _quiet_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _rrd_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--rrd",
        default=None,
        metavar="PATH",
        help="also write the training curves (return, length, loss, ε, collision rate per "
        "episode) as a rerun recording to PATH when training stops",
    )


_AGENTS = ("drqn", "rule-based", "planner", "random", "accelerate")


def _command(sub: Any, name: str, help_text: str, doc: str) -> argparse.ArgumentParser:
    return sub.add_parser(name, help=help_text, description=doc, formatter_class=_Formatter)


def _train_parser(sub: Any) -> None:
    train = _command(sub, "train", "train the DRQN", _TRAIN_DOC)
    _config_options(train, "default")
    _run_dir_option(train, "train")
    train.add_argument(
        "--resume",
        metavar="RUN_DIR",
        default=None,
        help="continue the run in RUN_DIR from its last checkpoint (uses its config.toml)",
    )
    _rrd_option(train)
    _quiet_option(train)


def _evaluate_parser(sub: Any) -> None:
    ev = _command(sub, "evaluate", "evaluate a trained run or a built-in agent", _EVALUATE_DOC)
    _agent_options(ev, "evaluate")
    ev.add_argument(
        "--episodes", type=int, default=None, help="episodes (default: evaluate.episodes)"
    )
    ev.add_argument("--seed", type=int, default=None, help="run.seed for the evaluation key")
    ev.add_argument(
        "--json", default=None, metavar="PATH", help="write the metrics as JSON ('-': stdout)"
    )
    _config_options(ev, "default")
    ev.add_argument("--quiet", action="store_true", help="no status messages on stderr")


def _reproduce_parser(sub: Any) -> None:
    rep = _command(
        sub,
        "reproduce",
        "train, evaluate and print the paper's Table III beside ours",
        _REPRODUCE_DOC,
    )
    _config_options(rep, "default")
    _run_dir_option(rep, "reproduce")
    _rrd_option(rep)
    _quiet_option(rep)


def _replay_parser(sub: Any) -> None:
    replay = _command(
        sub,
        "replay",
        "record episodes of a trained run or a built-in agent for the rerun viewer",
        _REPLAY_DOC,
    )
    _agent_options(replay, "record")
    replay.add_argument("--episodes", type=int, default=5, help="episodes to record")
    replay.add_argument(
        "--out",
        default=None,
        metavar="PATH",
        help="the .rrd file to write (default: RUN_DIR/episodes.rrd, or episodes.rrd "
        "without RUN_DIR)",
    )
    replay.add_argument("--seed", type=int, default=None, help="run.seed for the evaluation key")
    _config_options(replay, "default")
    replay.add_argument("--quiet", action="store_true", help="no line per episode")


def _sweep_parser(sub: Any) -> None:
    sweep = _command(
        sub,
        "sweep",
        "train and evaluate a grid of seeds x hyperparameters as one program per shape",
        _SWEEP_DOC,
    )
    sweep.add_argument("sweep_file", help="the sweep TOML (base config, [set], [axes])")
    _set_option(sweep, "override one field of every point (repeatable)")
    sweep.add_argument(
        "--out", default=None, help="results directory (default: runs/sweep-<file>-<UTC time>)"
    )
    sweep.add_argument(
        "--dry-run", action="store_true", help="validate, plan and describe; run nothing"
    )
    sweep.add_argument(
        "--resume", action="store_true", help="continue the sweep in --out from its checkpoints"
    )
    _quiet_option(sweep)
    sweep.add_argument(
        "--no-agents",
        action="store_true",
        help="do not keep the trained agents in OUT/agents (about 4 MB each, paper network)",
    )
    sweep.add_argument(
        "--strategy",
        choices=STRATEGIES,
        default=None,
        help="how a device trains its runs: batched (vmap) or one after another (map); "
        "default: the sweep file's, else auto (map on CPU, vmap elsewhere)",
    )
    sweep.add_argument(
        "--memory-gb",
        type=float,
        default=None,
        help="memory one call may use (default: the host's MemAvailable, or the devices' own)",
    )
    group = sweep.add_argument_group(
        "several processes (machines)",
        "give all three, or set JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES, JAX_PROCESS_ID",
    )
    group.add_argument("--coordinator", metavar="HOST:PORT", help="process 0's address")
    group.add_argument("--num-processes", type=int, metavar="N", help="processes in all")
    group.add_argument("--process-id", type=int, metavar="I", help="this process (0 … N-1)")


def _study_parser(sub: Any) -> None:
    study = _command(
        sub,
        "study",
        "configs x seeds trained and evaluated on the same episodes, beside the "
        "rule-based agent: Table III with intervals, and training curves",
        _STUDY_DOC,
    )
    study.add_argument(
        "--configs",
        default="paper,default,dqn",
        help="comma-separated config names in configs/ or TOML paths (one row each)",
    )
    study.add_argument("--seeds", type=int, default=5, help="seeds 0 … N-1 per config")
    study.add_argument(
        "--episodes", type=int, default=1000, help="greedy evaluation episodes per run"
    )
    _set_option(study, "override one field of every config (repeatable)")
    study.add_argument(
        "--eval-envs",
        default="",
        metavar="ENV_ID,...",
        help="also evaluate every config's trained agents among these envs' pedestrians, "
        "on the same episodes (one more row each, beside that env's rule-based agent)",
    )
    study.add_argument(
        "--out",
        default=None,
        help="study directory (default: runs/study-<config names>, so that running the "
        "command again continues it)",
    )
    study.add_argument(
        "--smooth", type=int, default=10, help="running mean (episodes) of the curves"
    )
    study.add_argument(
        "--no-png", action="store_true", help="skip curves.png (no matplotlib needed)"
    )
    study.add_argument(
        "--dry-run", action="store_true", help="validate and describe the study; run nothing"
    )
    study.add_argument(
        "--report-only",
        action="store_true",
        help="train nothing: the table and curves of the runs that have finished so far",
    )
    study.add_argument(
        "--results",
        metavar="PATH",
        help="also store the table's rows, this command and its wall time as section "
        "--section of this results file (e.g. docs/results.json; other sections stay)",
    )
    study.add_argument(
        "--section", help="the section of --results (default: the study directory's name)"
    )
    study.add_argument("--quiet", action="store_true", help="no progress bars")


def _frontier_parser(sub: Any) -> None:
    frontier = _command(
        sub,
        "frontier",
        "the rule-based family's safety/speed frontier and the privileged planner's ceiling "
        "(SPEC §9) on a config's evaluation episodes",
        _FRONTIER_DOC,
    )
    _config_options(frontier, "default")
    frontier.add_argument(
        "--episodes", type=int, default=None, help="episodes (default: evaluate.episodes)"
    )
    frontier.add_argument("--seed", type=int, default=None, help="run.seed for the evaluation key")
    frontier.add_argument(
        "--wide",
        action="store_true",
        help="sweep the wide grid (drqn_jax.experiments.frontier.WIDE_GRID, the evidence "
        "behind the default settings; about 25 min on 2 cores at 1000 episodes)",
    )
    frontier.add_argument(
        "--caps",
        default=",".join(f"{c:g}" for c in PLANNER_CAPS_KMH),
        metavar="KMH,...",
        help="the planner's speed caps (km/h, at most the speed limit)",
    )
    frontier.add_argument("--no-planner", action="store_true", help="the rule-based sweep only")
    frontier.add_argument(
        "--check",
        type=int,
        default=0,
        metavar="N",
        help="also evaluate N random rule-based settings (a reviewer's) and say how many lie "
        "above the frontier (stored as the section's comparison)",
    )
    frontier.add_argument(
        "--out", default=None, help="where to write frontier.json and frontier.png"
    )
    frontier.add_argument(
        "--results",
        metavar="PATH",
        help="also store both frontiers as section --section of this results file",
    )
    frontier.add_argument("--section", default="frontier", help="the section of --results")
    frontier.add_argument("--no-png", action="store_true", help="skip frontier.png")
    frontier.add_argument("--quiet", action="store_true", help="no status messages")


def _report_parser(sub: Any) -> None:
    report = _command(
        sub,
        "report",
        "fill the results blocks of documents from the results file a study wrote",
        _REPORT_DOC,
    )
    report.add_argument("documents", nargs="+", help="Markdown files with results blocks")
    report.add_argument(
        "--results", default="docs/results.json", help="the results file (study --results)"
    )
    report.add_argument("--quiet", action="store_true", help="no status messages")
    report.add_argument(
        "--check",
        action="store_true",
        help="change nothing: exit 1 if a document's blocks differ from the results file",
    )


def _bench_parser(sub: Any) -> None:
    bench = _command(
        sub,
        "bench",
        "run the benchmark suite (or one of its benchmarks) on this machine",
        _BENCH_DOC,
    )
    bench.add_argument(
        "name",
        nargs="?",
        default="all",
        choices=("all", "quick", *SUITE, *TOOLS),
        help="a benchmark of the suite, 'all' of them, 'quick' (figures of one config), "
        "or 'profile' (where a program's time goes, op by op)",
    )
    bench.add_argument(
        "args",
        nargs=argparse.REMAINDER,
        help="the benchmark's own options (drqn-jax bench NAME --help lists them)",
    )


def build_parser() -> argparse.ArgumentParser:
    """The ``drqn-jax`` parser: one subparser per command, each built by its own function."""
    parser = argparse.ArgumentParser(
        prog="drqn-jax",
        description="JAX DRQN for urban driving among pedestrians (Deshpande et al.)",
        formatter_class=_Formatter,
    )
    parser.add_argument("--version", action="version", version=f"drqn-jax {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_parser in (
        _train_parser,
        _evaluate_parser,
        _reproduce_parser,
        _replay_parser,
        _sweep_parser,
        _study_parser,
        _frontier_parser,
        _report_parser,
        _bench_parser,
    ):
        add_parser(sub)
    return parser


_REPORT_DOC = """Regenerate every block between '<!-- results:NAME -->' and '<!-- /results -->'
in the documents from section NAME of the results file (drqn-jax study --results FILE
--section NAME writes it): its table, comparisons, command and wall time, so that no
document retypes a number."""
_TRAIN_DOC = """Train the DRQN of a config; writes config.toml, metrics.csv, checkpoints,
evaluation.json and results.md to the run directory. Ctrl-C (or SIGTERM) saves a
checkpoint and exits with status 130; --resume continues bit-identically."""
_EVALUATE_DOC = """Evaluate a run directory's DRQN (or a sweep's or study's trained agent,
OUT/agents/run-NNNN) or a built-in agent greedily on the evaluation key and print the SPEC §8
metrics. --set changes the episodes, not the agent: e.g. --set env.id=... evaluates it among
other pedestrians, --seed 0 on a study's episodes."""
_REPRODUCE_DOC = """Train the DRQN with the config (default.toml), evaluate it and the
rule-based agent on evaluate.episodes episodes each, and print the paper's Table III beside
ours with the wall time."""
_REPLAY_DOC = """Record episodes of a run directory's greedy DRQN (with its four Q-values per
step) or of a built-in agent as a rerun recording: the map, the ego, the pedestrians coloured by
behaviour, the four grid channels, speed, action, reward and TTC on the timeline "step". Episode
i is episode i of `evaluate` (the config's evaluation key). View it with: rerun PATH"""
_SWEEP_DOC = """Run every point of a sweep file: points that share shapes train together in
compiled jit(vmap) calls, the runs sharded over all local devices, as many per call as the
memory plan allows; each run is evaluated on the same episodes. Writes results.md and
results.csv (mean, std, 95 % t-interval and IQM across seeds per setting) and runs.json
(every run), and every run's trained agent in OUT/agents/run-NNNN (for evaluate and
replay). Ctrl-C saves checkpoints (status 130); --resume continues, also a sweep
file given more points after the saved ones (more seeds). With several
processes each trains its slice of the runs and process 0 writes the results."""
_STUDY_DOC = """Train every config for seeds 0 … N-1 (one sweep over run.seed per
config, in OUT/<config>/), evaluate every run greedily on the same episodes (the first
seed's evaluation key), evaluate the rule-based agent on them, and write OUT/study.md
(the paper's Table III beside ours: collision-free % with a 95 % interval across seeds,
speed, distance, goal %, collisions per km), OUT/study.json, and the training curves
(average reward and steps per episode, mean and min-max over seeds) as OUT/curves.png
and OUT/curves.rrd. Each run's trained agent is OUT/<config>/agents/run-NNNN; --eval-envs
evaluates them among other pedestrians too (one more row per env). Ctrl-C saves checkpoints
(status 130); running the same command again continues the study, and with a larger
--seeds adds the new seeds to it; --eval-envs on a finished study only evaluates."""
_FRONTIER_DOC = """Sweep the rule-based agent over its parameters (v_max from 1 km/h to the
speed limit, lookahead, horizon, corridor margin) on the config's evaluation episodes, as
one compiled program, and keep its Pareto-efficient points (collision-free rate against
average speed): the frontier every agent's margin is measured against. Then play the
privileged planner (it sees the true state and plays the simulator forward: a ceiling,
never a learner's competitor) at each speed cap. Prints both, with the wall time of each;
writes OUT/frontier.json (every swept point) and OUT/frontier.png, and with --results the
points as a section of the results file."""
_BENCH_DOC = """Run the benchmark suite of benchmarks/ (a clone of the repository is
needed): each benchmark prints a Markdown table with the machine it ran on, and
--out DIR writes DIR/NAME.json and DIR/NAME.md. 'all' runs every benchmark with
the options --repeats, --out and --quick passed on to each. 'quick' prints
env steps/s and training throughput of one config (options --config, --set,
--num-envs, --steps, --iterations) and needs no clone."""

#: The suite's benchmarks, in the order ``drqn-jax bench all`` runs them.
SUITE = (
    "env_throughput",
    "stages",
    "peers",
    "roofline",
    "train_throughput",
    "evaluation",
    "sweep_throughput",
    "gymnasium_throughput",
)
#: Benchmark tools run by name only (not by ``all``): the op-by-op profile, and the
#: learners on outside benchmarks (gymnax; minutes of training, not a throughput figure).
TOOLS = ("profile", "gymnax_validation")


def _default_run_dir(prefix: str, config_name: str) -> Path:
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{prefix}-{Path(config_name).stem}-{stamp}"


def cmd_train(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    if args.resume is not None:
        if args.config != "default" or args.run_dir is not None:
            raise ConfigError(
                "--resume RUN_DIR continues with RUN_DIR's own config.toml and directory: "
                "drop --config and --run-dir (use --set for non-training fields)"
            )
        config = load_run(args.resume, tuple(args.overrides))
        run_dir = Path(args.resume)
    else:
        config = load_config(args.config, args.overrides)
        run_dir = Path(args.run_dir or _default_run_dir("train", args.config))
    resume = args.resume is not None
    return _train_and_evaluate(
        config, run_dir, resume, args.quiet, start, reproduce=False, rrd=args.rrd
    )


def _train_and_evaluate(
    config: Config,
    run_dir: Path,
    resume: bool,
    quiet: bool,
    start: float,
    *,
    reproduce: bool,
    rrd: str | None = None,
) -> int:
    """Train, then evaluate the DRQN (and, to reproduce Table III, the rule-based agent).

    With ``rrd`` the training curves of every recorded episode are written there
    once training stops (finished, interrupted or diverged: the last good state).
    """
    if rrd is not None and Path(rrd).is_dir():
        raise ConfigError(f"--rrd {rrd}: is a directory; give a file name such as training.rrd")
    result = train_run(config, run_dir, resume=resume, quiet=quiet)
    if rrd is not None:
        from drqn_jax.interop.recording import record_training

        try:
            record_training(rrd, recorded_metrics(result.state))
            print(f"training curves: {rrd} (view with: rerun {rrd})", file=sys.stderr)
        except OSError as err:  # the run itself is saved: report and go on
            print(f"error: --rrd {rrd}: {err}", file=sys.stderr)
    if result.status != "finished":
        print(("error: " if result.status == "diverged" else "") + result.message, file=sys.stderr)
        return EXIT_FAILED if result.status == "diverged" else EXIT_INTERRUPTED
    agents = [_trained(result)]
    if reproduce:
        agents.append(builtin_agent("rule-based", config))
    if not quiet:
        _say_evaluating(config, agents)
    results = evaluate_agents(config, agents, quiet=quiet)
    if reproduce:
        from drqn_jax.experiments.study import config_frontier

        if not quiet:
            print("sweeping the rule-based frontier on the same episodes...", file=sys.stderr)
        table = paper_comparison(results, config_frontier(config, planner=False))
    else:
        table = metrics_table(results)
    wall = time.perf_counter() - start
    write_evaluation(run_dir, results, {**_run_summary(result), "total_wall_time_s": wall}, table)
    print(table)
    print(
        f"\nwall time {wall:.1f} s (training {result.wall_time_s:.1f} s over "
        f"{int(result.state.recorded)} episodes, {int(result.state.grad_steps)} gradient steps)"
        f"\nrun directory: {run_dir}"
    )
    return EXIT_OK


def _say_evaluating(config: Config, agents: Sequence[Any]) -> None:
    """The status line of an evaluation (stderr): agents, episodes, world and key."""
    names = " and ".join(a.name for a in agents)
    print(
        f"evaluating {names} on {config['evaluate']['episodes']} episodes of "
        f"{config['env']['id']} (evaluation key of seed {config['run']['seed']})...",
        file=sys.stderr,
        flush=True,
    )


def _trained(result: Any) -> Any:
    params = result.trainer.agent_params(result.state)
    return drqn_agent(result.trainer.network, params, agent_name(result.trainer.config))


def _run_summary(result: Any) -> dict[str, Any]:
    state = result.state
    return {
        "run_dir": str(result.run_dir),
        "train_wall_time_s": result.wall_time_s,
        "compile_time_s": result.compile_time_s,
        "episodes": int(state.recorded),
        "env_steps": int(state.env_steps),
        "grad_steps": int(state.grad_steps),
        **selection(state.validation, state.hparams),
    }


def _chosen_agent(args: argparse.Namespace, overrides: list[str]) -> tuple[Config, Any, Any, Any]:
    """``(config, agent, network, network_params)`` for ``[RUN_DIR] --agent``.

    The trained agent (``--agent drqn``: the run's DRQN, DQN or PPO policy, named
    by :func:`agent_name`) comes from the run's last checkpoint (trained with the run's own
    config; ``overrides`` apply on top for the episodes); a built-in agent uses
    the run's config, or ``--config``. ``network`` is None for a built-in agent.
    """
    chosen = args.agent or ("drqn" if args.run_dir else "rule-based")
    if chosen != "drqn":
        source = Path(args.run_dir) / "config.toml" if args.run_dir else args.config
        config = load_config(source, overrides)
        return config, builtin_agent(chosen, config), None, None
    if args.run_dir is None:
        raise ConfigError("--agent drqn needs a RUN_DIR (a trained run)")
    network, params, meta = load_trained_network(load_run(args.run_dir, ()), args.run_dir)
    if not meta.get("finished", False):
        print(
            f"note: {args.run_dir} has not finished training "
            f"({meta.get('recorded')} episodes so far)",
            file=sys.stderr,
        )
    config = load_run(args.run_dir, tuple(overrides))
    name = agent_name(config.train_config())
    return config, drqn_agent(network, params, name), network, params


def cmd_evaluate(args: argparse.Namespace) -> int:
    overrides = list(args.overrides)
    if args.episodes is not None:
        overrides.append(f"evaluate.episodes={args.episodes}")
    if args.seed is not None:
        overrides.append(f"run.seed={args.seed}")
    config, agent, _, _ = _chosen_agent(args, overrides)
    start = time.perf_counter()
    seed, world = config["run"]["seed"], config["env"]["id"]
    if not args.quiet:
        _say_evaluating(config, [agent])
    (result,) = evaluate_agents(config, [agent], quiet=args.quiet)
    wall = time.perf_counter() - start
    # with --json - stdout carries only the JSON (pipe it to jq); the table goes to stderr
    table_out = sys.stderr if args.json == "-" else sys.stdout
    print(metrics_table([result]), file=table_out)
    print(
        f"\n{result['num_episodes']} episodes of {world}, evaluation key of seed {seed}, "
        f"{wall:.1f} s",
        file=table_out,
    )
    if args.json is not None:
        text = json.dumps({**json_ready(result), "seed": seed}, indent=2) + "\n"
        if args.json == "-":
            sys.stdout.write(text)
        else:
            Path(args.json).write_text(text)
    return EXIT_OK


def paper_comparison(results: list[dict[str, Any]], frontier: dict[str, Any]) -> str:
    """The paper's Table III rows (with the interval its 10 episodes allow) beside ours
    (one trained DRQN, then the rule-based agent), each with its margin to the rule-based
    frontier of ``frontier`` (:func:`~drqn_jax.experiments.frontier.world_frontier`), and
    the verdict on the paper's claim."""
    from drqn_jax.experiments.frontier import with_margin
    from drqn_jax.experiments.report import claim_verdict, study_table
    from drqn_jax.experiments.study import baseline_row, paper_rows

    world = frontier["world"]
    ours = [with_margin(baseline_row("drqn_jax", r, world=world), frontier) for r in results]
    return "\n\n".join(
        [
            study_table(paper_rows() + ours),
            claim_verdict(ours[0])
            + " One training seed: its interval holds the episodes' variation, not the"
            " training's (docs/results.md has five seeds).",
        ]
    )


def cmd_reproduce(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    config = load_config(args.config, args.overrides)
    run_dir = Path(args.run_dir or _default_run_dir("reproduce", args.config))
    return _train_and_evaluate(
        config, run_dir, False, args.quiet, start, reproduce=True, rrd=args.rrd
    )


def cmd_replay(args: argparse.Namespace) -> int:
    from drqn_jax.interop.recording import collect_episodes, write_episodes

    if args.episodes < 1:
        raise ConfigError(f"--episodes = {args.episodes}: must be an integer >= 1")
    overrides = list(args.overrides)
    if args.seed is not None:
        overrides.append(f"run.seed={args.seed}")
    config, agent, network, network_params = _chosen_agent(args, overrides)
    default_out = Path(args.run_dir) / "episodes.rrd" if args.run_dir else Path("episodes.rrd")
    out = Path(args.out) if args.out else default_out
    if out.is_dir():
        raise ConfigError(f"--out {out}: is a directory; give a file name such as episodes.rrd")
    env, env_params = config.make_env()
    _, eval_key = config.keys()
    record = collect_episodes(
        agent,
        eval_key,
        args.episodes,
        env,
        env_params,
        network=network,
        network_params=network_params,
    )
    try:
        write_episodes(out, record, env, env_params)
    except OSError as err:
        raise ConfigError(f"--out {out}: {err.strerror or err}") from None
    for i in range(0 if args.quiet else record.num_episodes):
        print(
            f"episode {i}: {int(record.length[i])} steps, "
            f"return {float(record.episode_return[i]):.2f}, {record.outcome(i)}"
        )
    seed, n = config["run"]["seed"], record.num_episodes
    print(f"wrote {n} episode{'s' if n != 1 else ''} of {agent.name} (seed {seed}) to {out}")
    print(f"view with: rerun {out}")
    return EXIT_OK


def _quick_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="drqn-jax bench quick", formatter_class=_Formatter)
    parser.add_argument("--num-envs", type=int, default=4096, help="parallel envs")
    parser.add_argument("--steps", type=int, default=200, help="env steps per timed call")
    parser.add_argument(
        "--iterations", type=int, default=20, help="training iterations per timed call"
    )
    _config_options(parser, "default")
    return parser


def _run_benchmark(name: str, args: Sequence[str]) -> int:
    """``python -m benchmarks.NAME ARGS`` of the clone this package was installed from, in
    a child process (this one's ``sys.path`` stays as it is); returns its exit status."""
    root = Path(__file__).resolve().parents[1]
    if not (root / "benchmarks" / "__init__.py").is_file():
        raise ConfigError(
            f"bench {name}: the suite lives in benchmarks/ of a clone of the repository "
            f"(not found beside {Path(__file__).parent}); install with pip install -e ."
        )
    path = os.pathsep.join(p for p in (str(root), os.environ.get("PYTHONPATH")) if p)
    command = [sys.executable, "-m", f"benchmarks.{name}", *args]
    return subprocess.run(command, env={**os.environ, "PYTHONPATH": path}).returncode


def cmd_bench(args: argparse.Namespace) -> int:
    if args.name == "quick":
        from drqn_jax.experiments.bench import bench_env, bench_train
        from drqn_jax.experiments.machine import machine_info, machine_lines

        quick = _quick_parser().parse_args(args.args)
        config = load_config(quick.config, quick.overrides)
        if quick.num_envs < 1 or quick.steps < 1 or quick.iterations < 1:
            raise ConfigError("--num-envs, --steps and --iterations must be >= 1")
        print(bench_env(config, quick.num_envs, quick.steps))
        print(bench_train(config, quick.iterations))
        print("\n".join(machine_lines(machine_info())))
        return EXIT_OK
    if args.name != "all":
        return _run_benchmark(args.name, args.args)
    common = argparse.ArgumentParser(prog="drqn-jax bench all")
    common.add_argument("--repeats", type=int)
    common.add_argument("--out", metavar="DIR")
    common.add_argument("--quick", action="store_true")
    options = common.parse_args(args.args)
    passed = ["--repeats", str(options.repeats)] if options.repeats else []
    passed += ["--out", options.out] if options.out else []
    passed += ["--quick"] if options.quick else []
    status = EXIT_OK
    for name in SUITE:
        print(f"\n# drqn-jax bench {name} {' '.join(passed)}\n", flush=True)
        status = max(status, _run_benchmark(name, passed))
    return status


def cmd_sweep(args: argparse.Namespace) -> int:
    import jax

    from drqn_jax.experiments.sweep import load_sweep, summarize_sweep, sweep_csv, sweep_table
    from drqn_jax.experiments.sweep_runner import (
        describe_plan,
        init_distributed,
        plan_calls,
        run_sweep,
    )

    dist = init_distributed(args.coordinator, args.num_processes, args.process_id)
    if dist.processes > 1 and args.out is None:
        raise ConfigError("several processes need --out (the same directory name on every one)")
    if args.resume and args.out is None:
        raise ConfigError("--resume needs --out DIR, the directory of the sweep to continue")
    if args.memory_gb is not None and not args.memory_gb > 0:
        raise ConfigError(f"--memory-gb = {args.memory_gb}: must be > 0")
    sweep = load_sweep(args.sweep_file, args.overrides)
    devices = len(jax.local_devices())
    budget = None if args.memory_gb is None else int(args.memory_gb * 1e9)
    calls = plan_calls(sweep, devices, dist, budget, "--memory-gb", args.strategy)
    if dist.leader:
        print(sweep.describe(), file=sys.stderr)
    print(describe_plan(calls, devices, dist), file=sys.stderr)
    if args.dry_run:
        return EXIT_OK
    out = Path(args.out or _default_run_dir("sweep", args.sweep_file))
    start = time.perf_counter()
    outcome = run_sweep(
        sweep,
        out,
        calls=calls,
        dist=dist,
        resume=args.resume,
        quiet=args.quiet,
        keep_agents=not args.no_agents,
    )
    if outcome.status == "interrupted":
        print(
            f"interrupted; checkpoints saved, continue with: drqn-jax sweep {args.sweep_file} "
            f"--out {out} --resume (and the same --set options)",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    if not dist.leader:
        return EXIT_OK
    rows = summarize_sweep(outcome.results)
    table = sweep_table(rows)
    atomic_write_text(out / "results.md", table + "\n")
    atomic_write_text(out / "results.csv", sweep_csv(rows))
    atomic_write_text(out / "runs.json", json.dumps(outcome.results, indent=2) + "\n")
    print(table)
    elapsed = time.perf_counter() - start
    print(f"\n{len(outcome.results)} runs in {elapsed:.1f} s; results in {out}")
    return EXIT_OK


def cmd_study(args: argparse.Namespace) -> int:
    from drqn_jax.experiments.study import plan_study, require_matplotlib, run_study

    configs = [c.strip() for c in args.configs.split(",") if c.strip()]
    if args.smooth < 1:
        raise ConfigError(f"--smooth {args.smooth}: must be an integer >= 1")
    eval_envs = [e.strip() for e in args.eval_envs.split(",") if e.strip()]
    arms = plan_study(configs, args.seeds, args.episodes, args.overrides, eval_envs)
    out = Path(args.out or Path("runs") / f"study-{'-'.join(a.name for a in arms)}")
    if args.results:
        _check_section(args.section or out.name)
    for arm in arms:
        print(f"{arm.name}: {arm.sweep.describe()}", file=sys.stderr)
    if not args.no_png:
        require_matplotlib()  # before hours of training, not after
    if args.dry_run:
        return EXIT_OK
    start = time.perf_counter()
    outcome = run_study(
        arms,
        out,
        smooth=args.smooth,
        png=not args.no_png,
        quiet=args.quiet,
        train=not args.report_only,
    )
    if outcome.status == "interrupted":
        print(
            f"interrupted; checkpoints saved, continue with the same command (--out {out})",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    wall = time.perf_counter() - start
    if args.results:
        from drqn_jax.experiments.machine import machine_info
        from drqn_jax.experiments.report import load_results, write_results

        about = {
            "command": args.command_line,
            "wall_time_s": wall,
            "continued": outcome.continued,
            "machine": machine_info(),
        }
        section = args.section or out.name
        earlier = load_results(args.results)["sections"].get(section)
        if args.report_only and earlier:  # the runs' provenance stays the command that made them
            about = {**earlier, "report_command": args.command_line}
        about["frontiers"] = outcome.frontiers
        write_results(args.results, section, outcome.rows, outcome.comparisons, about)
        print(f"rows stored as section {section!r} of {args.results}", file=sys.stderr)
        if not args.no_png and (out / "safety_speed.png").is_file():
            figure = Path(args.results).parent / "figures" / f"{section}-safety-speed.png"
            figure.parent.mkdir(parents=True, exist_ok=True)
            figure.write_bytes((out / "safety_speed.png").read_bytes())
            print(f"safety/speed figure: {figure}", file=sys.stderr)
    print(outcome.table)
    print(f"\nwall time {wall:.1f} s; study in {out}")
    return EXIT_OK


def cmd_report(args: argparse.Namespace) -> int:
    from drqn_jax.experiments.report import load_results, stale_documents, update_document

    if not Path(args.results).is_file():
        raise ConfigError(f"--results {args.results}: no such file (a study writes it)")
    record = load_results(args.results)
    missing = [d for d in args.documents if not Path(d).is_file()]
    if missing:
        raise ConfigError(f"{missing[0]}: no such document")
    try:
        stale = stale_documents(args.documents, record)
    except ValueError as err:
        raise ConfigError(str(err)) from None
    if args.check:
        for doc in stale:
            print(f"{doc}: its results blocks differ from {args.results}", file=sys.stderr)
        return EXIT_FAILED if stale else EXIT_OK
    for doc in stale:
        atomic_write_text(Path(doc), update_document(Path(doc).read_text(), record))
        if not args.quiet:
            print(f"updated {doc}", file=sys.stderr)
    return EXIT_OK


def cmd_frontier(args: argparse.Namespace) -> int:
    from drqn_jax.experiments.frontier import WIDE_GRID, grid_settings
    from drqn_jax.experiments.study import config_frontier

    config, caps = _frontier_config(args)
    settings = grid_settings(WIDE_GRID) if args.wide else None
    if not args.quiet:
        print(
            f"sweeping {len(settings) if settings else 'the default'} rule-based settings"
            + ("" if args.no_planner else f" and the planner at {len(caps)} caps")
            + f" on {config['evaluate']['episodes']} episodes of {config['env']['id']} "
            f"(evaluation key of seed {config['run']['seed']})...",
            file=sys.stderr,
            flush=True,
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


def _frontier_config(args: argparse.Namespace) -> tuple[Config, list[float]]:
    """``frontier``'s config (with --episodes and --seed) and --caps, checked before
    anything compiles."""
    overrides = list(args.overrides)
    if args.episodes is not None:
        overrides.append(f"evaluate.episodes={args.episodes}")
    if args.seed is not None:
        overrides.append(f"run.seed={args.seed}")
    config = load_config(args.config, overrides)
    try:
        caps = [float(c) for c in args.caps.split(",") if c.strip()]
    except ValueError:
        raise ConfigError(f"--caps {args.caps!r}: must be numbers (km/h), e.g. 5,10,15") from None
    if args.check < 0:
        raise ConfigError(f"--check {args.check}: must be an integer >= 0")
    if not args.no_png:
        from drqn_jax.experiments.figures import require_matplotlib

        require_matplotlib()
    if args.results:
        _check_section(args.section)
    return config, caps


def _frontier_outputs(
    args: argparse.Namespace,
    config: Config,
    record: dict[str, Any],
    checks: list[str],
    wall: float,
) -> None:
    """OUT/frontier.json (every swept point) and frontier.png; the section of --results
    (the frontiers' rows, the check, the wall times); the table on stdout."""
    from drqn_jax.experiments.report import study_table
    from drqn_jax.experiments.study import frontier_key, frontier_rows, paper_rows

    rows = paper_rows() + frontier_rows(record)
    out = Path(args.out or _default_run_dir("frontier", args.config))
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "frontier.json", json.dumps(record, indent=1) + "\n")
    if not args.no_png:
        from drqn_jax.experiments.figures import plot_safety_speed

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
    print(study_table(rows) + "".join(f"\n* {line}" for line in checks))
    print(
        f"\n{record['rule_based']['swept']} rule-based settings"
        + (f" and {len(record['planner']['points'])} planner caps" if "planner" in record else "")
        + f" on {record['episodes']} episodes of {record['world']}: "
        + ", ".join(f"{k.removesuffix('_wall_time_s')} {v:.1f} s" for k, v in times.items())
        + f"; {wall:.1f} s in all\nwritten to {out}"
    )


def _reviewer_check(config: Config, record: dict[str, Any], n: int) -> str:
    """``n`` random rule-based settings on ``record``'s episodes against its frontier."""
    from drqn_jax.experiments.frontier import frontier_vertices, random_settings, reviewer_check
    from drqn_jax.experiments.study import config_frontier

    seed = config["run"]["seed"]
    limit = config["env"]["v_ref"] / KMH
    tried = config_frontier(
        config, planner=False, settings=random_settings(n, seed, limit), keep_all=True
    )
    vertices = frontier_vertices(record["rule_based"]["points"])
    return reviewer_check(tried["rule_based"]["swept_points"], vertices, seed)


def _check_section(section: str) -> None:
    try:
        check_section(section)
    except ValueError as err:
        raise ConfigError(str(err)) from None


COMMANDS = {
    "train": cmd_train,
    "evaluate": cmd_evaluate,
    "reproduce": cmd_reproduce,
    "replay": cmd_replay,
    "sweep": cmd_sweep,
    "study": cmd_study,
    "frontier": cmd_frontier,
    "report": cmd_report,
    "bench": cmd_bench,
}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``drqn-jax`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    args.command_line = shlex.join(["drqn-jax", *(sys.argv[1:] if argv is None else argv)])
    try:
        return COMMANDS[args.command](args)
    except (ConfigError, CheckpointError) as err:
        print(f"drqn-jax {args.command}: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:  # outside training (compiling, evaluating): nothing to save
        print(f"drqn-jax {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
