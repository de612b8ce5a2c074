"""Rerun recordings of training curves (paper §V-E): one run's per-episode metrics
(timeline ``"episode"``) and a study's curves over seeds (timeline ``"env_steps"``)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from drqn_jax.interop.recording import collapsed_blueprint, recording_file, send_scalars

__all__ = ["record_study_curves", "record_training", "running_mean"]

_REQUIRED_METRICS = ("episode", "episode_return", "length", "collision", "mean_loss", "epsilon")
EPISODE_TIMELINE = "episode"
ENV_STEPS_TIMELINE = "env_steps"  # a study's curves
COLLISION_RATE_WINDOW = 20  # episodes in the running collision/goal rates (as the progress bar)


def running_mean(values: np.ndarray, window: int = COLLISION_RATE_WINDOW) -> np.ndarray:
    """(N,) float64 mean of ``values[max(0, k - window + 1) : k + 1]`` for each k."""
    values = np.asarray(values, np.float64)
    total = np.concatenate([[0.0], np.cumsum(values)])
    k = np.arange(len(values))
    start = np.maximum(0, k - window + 1)
    return (total[k + 1] - total[start]) / (k + 1 - start)


def record_training(path: str | Path, metrics: Mapping[str, np.ndarray]) -> None:
    """Save training curves to ``path``: ``metrics`` (N,) arrays per recorded episode, as
    ``recorded_metrics`` returns them; rates are running means."""
    missing = [name for name in _REQUIRED_METRICS if name not in metrics]
    if missing:
        raise ValueError(f"record_training: metrics lack {', '.join(missing)}")
    m = {name: np.asarray(v) for name, v in metrics.items()}
    episodes = m["episode"].astype(np.int64)
    curves = {
        "return": m["episode_return"],
        "length": m["length"],
        "loss": m["mean_loss"],
        "epsilon": m["epsilon"],
        "collision_rate": running_mean(m["collision"]),
    }
    if "goal" in m:
        curves["goal_rate"] = running_mean(m["goal"])
    if "distance" in m:
        curves["distance"] = m["distance"]
    if "mean_speed" in m:
        curves["mean_speed_kmh"] = m["mean_speed"].astype(np.float64) * 3.6
    blueprint = _series_blueprint({name: f"/training/{name}" for name in curves})
    with recording_file(path, blueprint) as rec:
        for name, values in curves.items():
            style = rr.SeriesLines(names=name)
            send_scalars(rec, f"training/{name}", episodes, values, EPISODE_TIMELINE, style)


def _series_blueprint(views: Mapping[str, str], timeline: str = EPISODE_TIMELINE) -> rrb.Blueprint:
    """One time-series view per ``name → origin entity``, on ``timeline``."""
    series = [rrb.TimeSeriesView(name=name, origin=o) for name, o in views.items()]
    return collapsed_blueprint(rrb.Grid(*series), timeline)


def record_study_curves(path: str | Path, curves: Mapping[str, Mapping[str, Any]]) -> None:
    """Save ``load_curves`` per config as ``curves/<metric>/<config>/{mean,low,high,seed<k>}``."""
    metrics = sorted({m for by_metric in curves.values() for m in by_metric})
    views = {m: f"/curves/{m}" for m in metrics}
    with recording_file(path, _series_blueprint(views, ENV_STEPS_TIMELINE)) as rec:
        for name, by_metric in curves.items():
            for metric, c in by_metric.items():
                series = {part: (c.env_steps, getattr(c, part)) for part in ("mean", "low", "high")}
                series |= {
                    f"seed{k}": xy for k, xy in enumerate(zip(c.seed_steps, c.seeds, strict=True))
                }
                for part, (at, values) in series.items():
                    entity = f"curves/{metric}/{name}/{part}"
                    style = rr.SeriesLines(names=f"{name} {part}")
                    send_scalars(rec, entity, at, values, ENV_STEPS_TIMELINE, style)
