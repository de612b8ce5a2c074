"""A learning curve: collision-free rate and speed against env steps, one run.

Usage::

    python -m benchmarks.learning_curve [--config pqn] [--set train.num_env_steps=2000000]
        [--points 10] [--episodes 1000] [--out DIR]

One run of the config (seed ``run.seed``) trains to ``train.num_env_steps`` and,
each time it passes one of ``--points`` evenly spaced marks, its greedy agent is
evaluated on ``--episodes`` episodes of the evaluation key, the same episodes at
every point (:func:`greedy_curve`). Where
``docs/results.json`` holds the rule-based frontier of the config's world on those
episodes (``drqn-jax frontier``, or a study), each point also gets
its margin over the frontier at its own speed (SPEC §9); none above the speed
limit, where the rule-based family and the planner, capped at it, have no point.

This is how a preset's env-step budget is chosen: train once to a
large budget and read where the curve stops rising. A curve read at a mark of a
longer run is not a run of that budget (the learning rate and ε anneal over the
whole budget); it says where the gains end. With ``--out DIR`` every point is
written to ``DIR/learning_curve.json`` as it lands.
"""

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import base_parser, markdown_table, report, write_json
from drqn_jax.agents import drqn_agent
from drqn_jax.config import Config, load_config
from drqn_jax.evaluation import evaluate
from drqn_jax.experiments.baselines import frontier_key
from drqn_jax.experiments.frontier import with_margin
from drqn_jax.experiments.host_loop import StopRequest, finite_training, run_chunks
from drqn_jax.experiments.report import margin_cell
from drqn_jax.experiments.runner import compiled_run, init_program
from drqn_jax.learners import make_train
from drqn_jax.learners.hyperparams import agent_name

RESULTS = Path(__file__).resolve().parent.parent / "docs" / "results.json"

COLUMNS = {
    "env_steps": "env steps",
    "train_s": "training s",
    "collision_free": "collision-free % (95 % CI)",
    "avg_speed_kmh": "avg speed (km/h)",
    "struck": "struck while stopped %",
    "margin": "margin over the rule-based frontier (pts)",
}


#: What a point of :func:`greedy_curve` keeps of its evaluation (SPEC §8 names).
GREEDY_KEYS = (
    "num_episodes",
    "collision_free_rate",
    "collision_free_ci",
    "struck_while_stopped_rate",
    "goal_rate",
    "avg_speed_kmh",
    "avg_speed_authors_kmh",
    "avg_distance_m",
    "avg_distance_collision_free_m",
    "avg_return",
)


def greedy_curve(
    config: Config,
    points: int,
    episodes: int,
    on_point: Callable[[dict[str, Any]], None] | None = None,
    first: int | None = None,
) -> tuple[str, list[dict[str, Any]]]:
    """Train one run of ``config`` and evaluate its greedy agent on the same ``episodes``
    at ``points`` evenly spaced env-step marks (at the first chunk boundary past each).

    Returns ``(status, points)``; each point has ``env_steps``, ``train_s``, ``eval_s`` and
    :data:`GREEDY_KEYS`. ``on_point`` sees each; ``first`` stops after that many points.
    """
    total = config["train"]["num_env_steps"]
    if total < 1:
        raise ValueError("greedy_curve: set train.num_env_steps (the curve's env-step axis)")
    if points < 1 or episodes < 1:
        raise ValueError(f"greedy_curve: points = {points}, episodes = {episodes}: must be >= 1")
    trainer = make_train(config.train_config())
    env, env_params = config.make_env()
    train_key, eval_key = config.keys()
    marks = [total * (i + 1) // points for i in range(points)]
    found: list[dict[str, Any]] = []
    clock = {"train": 0.0, "since": time.perf_counter(), "passed": 0}

    def at_chunk(state: Any) -> None:
        passed = sum(int(state.env_steps) >= m for m in marks)
        if passed == clock["passed"]:
            return
        clock["passed"] = passed
        clock["train"] += time.perf_counter() - clock["since"]
        start = time.perf_counter()
        agent = drqn_agent(trainer.network, trainer.agent_params(state), agent_name(trainer.config))
        result = evaluate(agent, eval_key, episodes, env, env_params)
        point = {
            "env_steps": int(state.env_steps),
            "train_s": clock["train"],
            "eval_s": time.perf_counter() - start,
            **{k: result[k] for k in GREEDY_KEYS},
        }
        found.append(point)
        if on_point is not None:
            on_point(point)
        if first is not None and len(found) >= first:
            stop.request()
        clock["since"] = time.perf_counter()

    stop = StopRequest()
    state = init_program(trainer)(train_key)
    status, _, _ = run_chunks(
        compiled_run(trainer, state),  # train's chunk program
        state,
        finished=lambda s: bool(s.finished),
        stop=stop,
        save=lambda s, n: None,
        every_s=float("inf"),
        healthy=lambda s: bool(finite_training(s)),
        on_chunk=at_chunk,
    )
    if first is not None and len(found) >= first:
        status = f"first {len(found)} of {points} marks"
    return status, found


def stored_frontier(config: Config, results: Path = RESULTS) -> dict[str, Any] | None:
    """The rule-based frontier of ``config``'s world and evaluation episodes in any
    section of ``results`` (``docs/results.json``, under :func:`frontier_key`), or None."""
    if not results.is_file():
        return None
    sections = json.loads(results.read_text(encoding="utf-8")).get("sections", {})
    for section in sections.values():
        record = section.get("frontiers", {}).get(frontier_key(config))
        if record is not None:
            return record
    return None


def _cells(point: dict[str, Any]) -> dict[str, Any]:
    low, high = point["collision_free_ci"]
    return {
        **point,
        "collision_free": f"{100 * point['collision_free_rate']:.1f} "
        f"({100 * low:.1f}–{100 * high:.1f})",
        "struck": 100 * point["struck_while_stopped_rate"],
        "margin": margin_cell(point),
    }


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = base_parser("learning_curve", __doc__)
    parser.add_argument("--config", default="pqn", help="config name or TOML (default pqn)")
    parser.add_argument(
        "--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override"
    )
    parser.add_argument("--points", type=int, default=10, help="evaluations (default 10)")
    parser.add_argument(
        "--episodes", type=int, default=1000, help="episodes per evaluation (default 1000)"
    )
    parser.add_argument(
        "--first",
        type=int,
        default=None,
        metavar="N",
        help="stop after the first N marks (the start of a curve, e.g. on another machine)",
    )
    args = parser.parse_args(argv)
    if args.points < 1 or args.episodes < 1 or (args.first is not None and args.first < 1):
        parser.error("--points, --episodes and --first must be >= 1")
    config = load_config(args.config, [*args.set, f"evaluate.episodes={args.episodes}"])
    frontier = stored_frontier(config)
    limit_kmh = config.speed_limit_kmh()
    out = None if args.out is None else Path(args.out)
    partial = {"config": config.values, "points": []}
    start = time.perf_counter()

    def landed(point: dict[str, Any]) -> None:
        if frontier is not None:  # a single policy: Wilson, shifted; none above the limit
            point.update(with_margin(point, frontier, limit_kmh))
        partial["points"].append(point)
        cells = _cells(point)
        print(" | ".join(str(cells[k]) for k in COLUMNS), flush=True)
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
            write_json(out / "learning_curve.json", partial)

    status, points = greedy_curve(config, args.points, args.episodes, landed, args.first)
    result = {
        "config_name": args.config,
        "overrides": args.set,
        "status": status,
        "frontier": "docs/results.json" if frontier is not None else None,
        "points": points,
        "wall_s": time.perf_counter() - start,
        "config": config.values,
    }
    lines = [
        f"`{args.config}` ({', '.join(args.set) or 'as shipped'}), seed "
        f"{config['run']['seed']}: greedy agent on {args.episodes} evaluation episodes at "
        f"{args.points} marks of {config['train']['num_env_steps']:,} env steps; run "
        f"{status}, wall time {result['wall_s']:.0f} s (evaluations included).",
        "",
        *markdown_table([_cells(p) for p in points], COLUMNS),
    ]
    if frontier is None:
        lines += ["", "No stored frontier for this world and these episodes: no margin."]
    return report("learning_curve", "Learning curve", result, lines, args.out, argv)


if __name__ == "__main__":
    main()
