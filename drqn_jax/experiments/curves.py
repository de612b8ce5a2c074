"""A study's figures, each on a pyplot-free Figure: training curves against env steps (paper
Fig. 4, :func:`load_curves`, :func:`plot_curves`) and the safety/speed figure (SPEC §9,
:func:`plot_safety_speed`)."""

import csv
import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from drqn_jax.experiments.frontier import frontier_vertices
from drqn_jax.experiments.report import PAPER_WORLD
from drqn_jax.interop.recording import running_mean
from drqn_jax.learners.hyperparams import NOT_LEARNED

#: The curves of the paper's "Training performance" figure: metrics.csv column, label.
CURVES = (
    ("episode_return", "average reward (return per episode)"),
    ("length", "steps per episode"),
)
#: Points of a :class:`Curve`'s env-step grid.
CURVE_POINTS = 200


@dataclasses.dataclass(frozen=True)
class Curve:
    """A training curve over seeds against env steps (not episodes, which favour learners that end
    episodes early). ``env_steps`` (G,): grid up to the fewest steps any seed's first E episodes
    took; ``mean``, ``low``, ``high`` (G,): mean and min–max over seeds of the ``smooth``-episode
    running mean; ``seeds``, ``seed_steps`` (S, E): raw values and cumulative env steps."""

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
    fig = Figure(figsize=(11, 4), layout="constrained")
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
    _save_png(fig, path)


def _save_png(fig: Figure, path: str | Path) -> None:
    """Write ``fig`` as a PNG at ``path`` (120 dpi, Agg), creating its directory."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, format="png")


def _points(ax: Any, points: Sequence[Mapping[str, Any]], *fmt: str, **style: Any) -> None:
    xs = [p["avg_speed_kmh"] for p in points]
    ys = [100 * p["collision_free_rate"] for p in points]
    ax.plot(xs, ys, *fmt, **style)


def _agent(ax: Any, row: Mapping[str, Any], label: str, color: str | None = None) -> None:
    """One row: its mean with its collision-free interval, its seeds as dots."""
    low, high = (100 * x for x in row["collision_free_ci"])
    mean = 100 * row["collision_free_rate"]
    bar = ax.errorbar(
        row["avg_speed_kmh"],
        mean,
        yerr=[[mean - low], [high - mean]],
        fmt="s" if row.get("learned") == NOT_LEARNED else "o",
        color=color,
        capsize=3,
        label=label,
    )
    seeds = row.get("per_seed") or []
    if len(seeds) > 1:
        _points(ax, seeds, ls="none", marker=".", alpha=0.5, color=bar[0].get_color())


def plot_safety_speed(
    rows: Sequence[Mapping[str, Any]], frontier: Mapping[str, Any], path: str | Path
) -> None:
    """Collision-free rate against average speed (SPEC §9) as a PNG: ``rows`` of
    ``frontier``'s world (and the paper's) over that world's frontiers."""
    fig = Figure(figsize=(8, 5.5), layout="constrained")
    ax = fig.subplots()
    rule = frontier["rule_based"]["points"]
    vertices = [{"avg_speed_kmh": v, "collision_free_rate": r} for v, r in frontier_vertices(rule)]
    swept = frontier["rule_based"]["swept"]
    _points(ax, vertices, "-", color="0.35", label=f"rule-based frontier ({swept} settings swept)")
    _points(ax, rule, ls="none", marker="x", color="0.35", label="its Pareto points")
    if "planner" in frontier:
        caps = sorted(frontier["planner"]["points"], key=lambda p: p["avg_speed_kmh"])
        ceiling = "privileged planner (true state + simulator): ceiling"
        _points(ax, caps, ls="--", marker="^", color="tab:green", label=ceiling)
    for row in rows:
        if row["world"] == PAPER_WORLD:
            _agent(ax, row, f"paper (CARLA), 10 episodes: {row['agent']}", color="k")
        elif row["world"] == frontier["world"] and "params" not in row:  # not a frontier point
            _agent(ax, row, f"{row['label'].removeprefix('drqn_jax: ')} ({row['agent']})")
    ax.set_xlabel("average speed (km/h)")
    ax.set_ylabel("collision-free episodes (%)")
    ax.set_ylim(-2, 102)
    ax.set_xlim(left=0)
    ax.grid(alpha=0.3)
    ax.set_title(
        f"{frontier['world']}: {frontier['episodes']} evaluation episodes (seed "
        f"{frontier['seed']}); the paper's rows are CARLA, 10 episodes each",
        fontsize=9,
    )
    ax.legend(fontsize=7, loc="upper right")
    _save_png(fig, path)
