"""The study's safety/speed figure (SPEC §9): frontiers, the paper's points and every agent,
from a results section's rows alone. Every PNG is drawn on a pyplot-free :func:`figure`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure

from drqn_jax.experiments.frontier import frontier_vertices
from drqn_jax.experiments.report import PAPER_WORLD
from drqn_jax.learners.hyperparams import NOT_LEARNED

__all__ = ["figure", "plot_safety_speed", "save_png"]


def figure(width: float, height: float) -> Figure:
    """A matplotlib figure of ``width`` × ``height`` inches with the constrained layout."""
    return Figure(figsize=(width, height), layout="constrained")


def save_png(fig: Figure, path: str | Path) -> None:
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
    fig = figure(8, 5.5)
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
    save_png(fig, path)
