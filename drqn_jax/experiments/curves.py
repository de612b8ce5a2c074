"""A study's training curves (the paper's "Training performance" figure, Fig. 4):
each config's per-episode metrics over its seeds, against env steps, and their PNG.
"""

from __future__ import annotations

import csv
import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from drqn_jax.experiments.figures import require_matplotlib
from drqn_jax.interop.training_recording import running_mean

__all__ = ["CURVES", "Curve", "load_curves", "plot_curves"]

#: The curves of the paper's "Training performance" figure: metrics.csv column, label.
CURVES = (
    ("episode_return", "average reward (return per episode)"),
    ("length", "steps per episode"),
)


#: Points of a :class:`Curve`'s env-step grid.
CURVE_POINTS = 200


@dataclasses.dataclass(frozen=True)
class Curve:
    """A training curve over seeds against env steps (issue 41: a learner that ends
    episodes early or runs many envs gets no credit from an episode axis).

    ``env_steps`` (G,): a common grid from 0 to the fewest env steps any seed took;
    ``mean``, ``low``, ``high`` (G,): the mean and min–max across seeds of each seed's
    running mean over ``smooth`` episodes, read at the grid (linear between episodes);
    ``seeds`` (S, E): each seed's raw values per training episode, in the order
    they ended; ``seed_steps`` (S, E): the env steps taken when each had ended
    (the running total of episode lengths).
    """

    env_steps: np.ndarray
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray
    seeds: np.ndarray
    seed_steps: np.ndarray


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return {}
    return {name: np.array([float(r[name]) for r in rows]) for name in rows[0]}


def load_curves(metrics_files: Sequence[Path], smooth: int = 10) -> dict[str, Curve]:
    """The :data:`CURVES` of one config over its seeds' ``metrics.csv`` files, against
    env steps (:class:`Curve`).

    Seeds are cut to the episodes they all recorded. Raises ValueError when a
    file is missing or empty.
    """
    if smooth < 1:
        raise ValueError(f"smooth = {smooth!r}: must be an integer >= 1")
    tables = []
    for path in metrics_files:
        if not path.is_file():
            raise ValueError(f"{path}: no training metrics (has the run finished?)")
        table = _read_csv(path)
        if not table:
            raise ValueError(f"{path}: no recorded episodes")
        tables.append(table)
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
    """The paper's "Training performance" figure for every config: a PNG at ``path``.

    ``curves``: config name → :func:`load_curves`. Needs matplotlib (the ``plots`` extra).
    """
    plt = require_matplotlib()
    fig, axes = plt.subplots(1, len(CURVES), figsize=(11, 4), constrained_layout=True)
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
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
