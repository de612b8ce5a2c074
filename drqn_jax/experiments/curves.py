"""Learning curves: a study's training curves against env steps (paper Fig. 4,
:func:`load_curves`, :func:`plot_curves`) and one run's greedy agent evaluated at env-step
marks while it trains (:func:`greedy_curve`).
"""

from __future__ import annotations

import csv
import dataclasses
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drqn_jax.agents import drqn_agent
from drqn_jax.config import Config
from drqn_jax.evaluation import evaluate
from drqn_jax.experiments.figures import figure, save_png
from drqn_jax.experiments.host_loop import StopRequest, finite_training, run_chunks
from drqn_jax.experiments.runner import compiled_run, init_program
from drqn_jax.interop.recording import running_mean
from drqn_jax.learners import make_train
from drqn_jax.learners.hyperparams import agent_name

__all__ = ["CURVES", "GREEDY_KEYS", "Curve", "greedy_curve", "load_curves", "plot_curves"]

#: The curves of the paper's "Training performance" figure: metrics.csv column, label.
CURVES = (
    ("episode_return", "average reward (return per episode)"),
    ("length", "steps per episode"),
)
#: Points of a :class:`Curve`'s env-step grid.
CURVE_POINTS = 200


@dataclasses.dataclass(frozen=True)
class Curve:
    """A training curve over seeds against env steps (not episodes, which favour learners
    that end episodes early).

    ``env_steps`` (G,): grid up to the fewest steps any seed's first E episodes took;
    ``mean``, ``low``, ``high`` (G,): mean and min–max over seeds of the ``smooth``-episode
    running mean; ``seeds``, ``seed_steps`` (S, E): raw values and cumulative env steps.
    """

    env_steps: np.ndarray
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray
    seeds: np.ndarray
    seed_steps: np.ndarray


def load_curves(metrics_files: Sequence[Path], smooth: int = 10) -> dict[str, Curve]:
    """The :data:`CURVES` of one config from its seeds' ``metrics.csv`` files, cut to the
    episodes all recorded; ValueError if a file is missing or empty."""
    if smooth < 1:
        raise ValueError(f"smooth = {smooth!r}: must be an integer >= 1")
    tables = []
    for path in metrics_files:
        if not path.is_file():
            raise ValueError(f"{path}: no training metrics (has the run finished?)")
        with path.open(newline="") as f:
            rows = list(csv.DictReader(f))
        if not rows:
            raise ValueError(f"{path}: no recorded episodes")
        tables.append({name: np.array([float(r[name]) for r in rows]) for name in rows[0]})
    n = min(len(t["episode"]) for t in tables)
    steps = np.stack([np.cumsum(t["length"][:n]) for t in tables])
    grid = np.linspace(0.0, steps[:, -1].min(), CURVE_POINTS)
    curves = {}
    for column, _ in CURVES:
        raw = np.stack([t[column][:n] for t in tables])
        read = np.stack(
            [np.interp(grid, x, running_mean(y, smooth)) for x, y in zip(steps, raw, strict=True)]
        )
        curves[column] = Curve(
            env_steps=grid,
            mean=read.mean(axis=0),
            low=read.min(axis=0),
            high=read.max(axis=0),
            seeds=raw,
            seed_steps=steps,
        )
    return curves


def plot_curves(curves: Mapping[str, Mapping[str, Curve]], path: str | Path, smooth: int) -> None:
    """The paper's "Training performance" figure (config → :func:`load_curves`) as a PNG."""
    fig = figure(11, 4)
    axes = fig.subplots(1, len(CURVES))
    for ax, (column, label) in zip(axes, CURVES, strict=True):
        for name, by_metric in curves.items():
            c = by_metric[column]
            seeds = c.seeds.shape[0]
            plural = "s" if seeds > 1 else ""
            (line,) = ax.plot(c.env_steps, c.mean, label=f"{name} ({seeds} seed{plural})")
            ax.fill_between(c.env_steps, c.low, c.high, color=line.get_color(), alpha=0.2, lw=0)
        ax.set_xlabel("env steps (thousands)")
        ax.xaxis.set_major_formatter(lambda x, _: f"{x / 1000:g}")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle(
        f"Mean and min–max over seeds of a running mean over {smooth} training episodes",
        fontsize=10,
    )
    axes[0].legend(fontsize=8)
    save_png(fig, path)


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
