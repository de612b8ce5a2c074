"""The ``drqn-jax`` command line (it only parses; :mod:`drqn_jax.commands` runs).

Exit statuses: 0 done; 1 the run failed (non-finite loss; last good checkpoint
kept); 2 a configuration, usage or checkpoint problem; 130 interrupted (after a
checkpoint).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence
from typing import Any

from drqn_jax import __version__
from drqn_jax.agents.shipped import shipped_agents
from drqn_jax.commands.bench import SUITE, TOOLS, cmd_bench
from drqn_jax.commands.frontier import cmd_frontier
from drqn_jax.commands.help import (
    BENCH_DOC,
    EVALUATE_DOC,
    EXPORT_DOC,
    FRONTIER_DOC,
    REPLAY_DOC,
    REPORT_DOC,
    REPRODUCE_DOC,
    STUDY_DOC,
    SWEEP_DOC,
    TRAIN_DOC,
)
from drqn_jax.commands.runs import (
    cmd_evaluate,
    cmd_export,
    cmd_replay,
    cmd_reproduce,
    cmd_train,
)
from drqn_jax.commands.study import cmd_report, cmd_study
from drqn_jax.commands.sweep import cmd_sweep
from drqn_jax.config import ConfigError, config_names
from drqn_jax.experiments.checkpoint import CheckpointError
from drqn_jax.experiments.frontier import PLANNER_CAPS_KMH
from drqn_jax.experiments.runner import (
    EXIT_INTERRUPTED,
    EXIT_USAGE,
)
from drqn_jax.experiments.sweep import STRATEGIES

__all__ = ["main"]


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Help with each option's default, unless the text names it or it says nothing."""

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
    shipped = shipped_agents()
    parser.add_argument(
        "--agent",
        choices=_AGENTS + shipped,
        default=None,
        help=f"agent to {verb}; drqn: the run's trained agent, whatever its learner; planner: "
        "the privileged planner, which sees the true state and plays the simulator forward "
        "(a ceiling, not a learner; [planner] of the config)"
        + (f"; {', '.join(shipped)}: a trained agent shipped with drqn_jax " if shipped else " ")
        + "(default: drqn with RUN_DIR, rule-based without)",
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
    train = _command(sub, "train", "train the DRQN", TRAIN_DOC)
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
    ev = _command(sub, "evaluate", "evaluate a trained run or a built-in agent", EVALUATE_DOC)
    _agent_options(ev, "evaluate")
    ev.add_argument("--episodes", type=int, help="episodes (default: evaluate.episodes)")
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
        REPRODUCE_DOC,
    )
    rep.add_argument(
        "--train",
        action="store_true",
        help="train the agent again first (the shipped agent's config, or --config), "
        "with an estimate of how long on this device",
    )
    rep.add_argument(
        "--config",
        default=None,
        help="with --train: a TOML file or a name in configs/ to train instead of the "
        "shipped agent's config",
    )
    _set_option(rep, "override one field (repeatable), e.g. --set evaluate.episodes=100")
    _run_dir_option(rep, "reproduce")
    _rrd_option(rep)
    _quiet_option(rep)


def _export_parser(sub: Any) -> None:
    export = _command(
        sub,
        "export",
        "write a finished run's trained agent alone (a few MB) to a directory",
        EXPORT_DOC,
    )
    export.add_argument(
        "run_dir", help="a finished run directory (drqn-jax train) or a sweep's OUT/agents/run-NNNN"
    )
    export.add_argument("out", help="the directory to write")
    export.add_argument(
        "--command",
        required=True,
        dest="training_command",
        metavar="TEXT",
        help="the command that trained the run, kept in OUT/provenance.json",
    )
    export.add_argument("--quiet", action="store_true", help="no status message")


def _replay_parser(sub: Any) -> None:
    replay = _command(
        sub,
        "replay",
        "record episodes of a trained run or a built-in agent for the rerun viewer",
        REPLAY_DOC,
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
        SWEEP_DOC,
    )
    sweep.add_argument("sweep_file", help="the sweep TOML (base config, [set], [axes])")
    _set_option(sweep, "override one field of every point (repeatable)")
    sweep.add_argument("--out", help="results directory (default: runs/sweep-<file>-<time>)")
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
        STUDY_DOC,
    )
    study.add_argument(
        "--configs",
        default="paper,default,dqn",
        help="comma-separated config names in configs/ or TOML paths (one row each)",
    )
    study.add_argument("--seeds", type=int, default=5, help="seeds 0 … N-1 per config")
    study.add_argument("--episodes", type=int, default=1000, help="evaluation episodes per run")
    _set_option(study, "override one field of every config (repeatable)")
    study.add_argument(
        "--eval-envs",
        default="",
        metavar="ENV_ID,...",
        help="also evaluate every config's trained agents among these envs' pedestrians, "
        "on the same episodes (one more row each, beside that env's rule-based agent)",
    )
    study.add_argument("--out", default=None, help="study directory (runs/study-<configs>)")
    study.add_argument("--smooth", type=int, default=10, help="running mean of the curves")
    study.add_argument("--no-png", action="store_true", help="skip curves.png and safety_speed.png")
    study.add_argument(
        "--dry-run", action="store_true", help="validate and describe the study; run nothing"
    )
    study.add_argument(
        "--estimate",
        action="store_true",
        help="time one training chunk of every config on this device and print the "
        "study's training wall time; train nothing",
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
    study.add_argument("--section", help="the section of --results (default: OUT's name)")
    study.add_argument(
        "--runs-store",
        metavar="PATH",
        help="keep an interrupted study's finished runs here, for the same command in a "
        "fresh --out; removed once it finishes (default with --results: "
        "finished-runs/SECTION.json beside the results file)",
    )
    study.add_argument("--quiet", action="store_true", help="no progress bars")


def _frontier_parser(sub: Any) -> None:
    frontier = _command(
        sub,
        "frontier",
        "the rule-based family's safety/speed frontier and the privileged planner's ceiling "
        "(SPEC §9) on a config's evaluation episodes",
        FRONTIER_DOC,
    )
    _config_options(frontier, "default")
    frontier.add_argument("--episodes", type=int, help="episodes (default: evaluate.episodes)")
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
    frontier.add_argument("--out", default=None, help="where to write frontier.json/.png")
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
        REPORT_DOC,
    )
    report.add_argument("documents", nargs="+", help="Markdown files with results blocks")
    report.add_argument("--results", default="docs/results.json", help="the results file")
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
        BENCH_DOC,
    )
    bench.add_argument(
        "name",
        nargs="?",
        default="all",
        choices=("all", "quick", *SUITE, *TOOLS),
        help="a benchmark of the suite, 'all' of them, or 'quick' (figures of one config)",
    )
    bench.add_argument(
        "args",
        nargs=argparse.REMAINDER,
        help="the benchmark's own options (drqn-jax bench NAME --help lists them)",
    )


def build_parser() -> argparse.ArgumentParser:
    """The ``drqn-jax`` parser: one subparser per command."""
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
        _export_parser,
        _sweep_parser,
        _study_parser,
        _frontier_parser,
        _report_parser,
        _bench_parser,
    ):
        add_parser(sub)
    return parser


def _quick_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="drqn-jax bench quick", formatter_class=_Formatter)
    parser.add_argument("--num-envs", type=int, default=4096, help="parallel envs")
    parser.add_argument("--steps", type=int, default=200, help="env steps per timed call")
    parser.add_argument(
        "--iterations", type=int, default=20, help="training iterations per timed call"
    )
    parser.add_argument(
        "--decision-steps",
        type=int,
        nargs="+",
        default=None,
        metavar="K",
        help="time training at each env.decision_steps K side by side (default: the config's)",
    )
    _config_options(parser, "default")
    return parser


def _bench_all_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="drqn-jax bench all")
    parser.add_argument("--repeats", type=int)
    parser.add_argument("--out", metavar="DIR")
    parser.add_argument("--quick", action="store_true")
    return parser


def _bench(args: argparse.Namespace) -> int:
    """``bench``'s arguments after the benchmark's name, parsed here for quick and all."""
    if args.name in ("quick", "all"):
        parser = _quick_parser() if args.name == "quick" else _bench_all_parser()
        args.options = parser.parse_args(args.args)
    return cmd_bench(args)


COMMANDS = {
    "train": cmd_train,
    "evaluate": cmd_evaluate,
    "reproduce": cmd_reproduce,
    "replay": cmd_replay,
    "export": cmd_export,
    "sweep": cmd_sweep,
    "study": cmd_study,
    "frontier": cmd_frontier,
    "report": cmd_report,
    "bench": _bench,
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
