"""Hyperparameter sweeps as one compiled program per shape, sharded over devices.

A sweep file (TOML) names a base config and axes::

    base = "smoke"                      # a config name or path
    mode = "product"                    # or "zip": the i-th values of every axis
    [set]                               # overrides shared by every point
    "train.num_episodes" = 12
    [axes]                              # "section.field" = list, or a range table
    "run.seed" = { start = 0, stop = 4 }                    # 0, 1, 2, 3
    "train.learning_rate" = [1e-3, 3e-4]
    "train.gamma" = { start = 0.9, stop = 0.99, num = 3 }   # linspace, ends included

Every point is a full :class:`~drqn_jax.config.Config`, validated before
anything compiles. Points whose shapes agree (static env parameters, network,
training sizes) form one program: ``jit(vmap(train))`` over their PRNG keys,
``Hyperparams`` and ``EnvParams``; an axis that changes shapes (network
width, pedestrian count, window …) splits the sweep into several programs,
listed by :meth:`Sweep.describe` before any runs. The run axis is sharded over
all devices with a ``NamedSharding`` on a one-axis ``Mesh``; runs are padded
to a multiple of the device count with copies of the last run, and the copies
are dropped. Each run's results are bit-identical to the same run alone and do
not depend on the device count (tests/test_sweep.py).

Evaluation: every run is evaluated greedily on the same episodes — the
evaluation key of the base config — so runs differ only by their training.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from drqn_jax.agents import drqn_agent
from drqn_jax.config import (
    TRAIN_SIZES,
    Config,
    ConfigError,
    load_config,
    parse_override,
    toml_value,
)
from drqn_jax.evaluation import episode_keys, run_episodes, summarize
from drqn_jax.train import make_train

__all__ = [
    "Sweep",
    "SweepPoint",
    "evaluate_runs",
    "interquartile_mean",
    "load_sweep",
    "run_sweep",
    "summarize_sweep",
    "sweep_csv",
    "sweep_table",
    "train_runs",
]

MODES = ("product", "zip")


@dataclasses.dataclass(frozen=True)
class SweepPoint:
    """One run: its index in the sweep, axis values and resolved config."""

    index: int
    values: dict[str, Any]
    config: Config

    @property
    def setting(self) -> tuple[tuple[str, Any], ...]:
        """The axis values other than the seed: the runs a results row pools."""
        return tuple((k, v) for k, v in self.values.items() if k != "run.seed")


@dataclasses.dataclass(frozen=True)
class Sweep:
    """A validated sweep: its points and their grouping into programs."""

    base: str
    axes: dict[str, list[Any]]
    points: list[SweepPoint]

    def programs(self) -> list[list[SweepPoint]]:
        """Points grouped by shapes, in order of first appearance: one program each."""
        groups: dict[Any, list[SweepPoint]] = {}
        for point in self.points:
            groups.setdefault(shape_key(point.config), []).append(point)
        return list(groups.values())

    def describe(self) -> str:
        """What will run: points, programs and which axes split them."""
        programs = self.programs()
        lines = [
            f"sweep over {len(self.points)} runs from {self.base!r}: "
            + ", ".join(f"{k} ({len(v)})" for k, v in self.axes.items())
        ]
        if len(programs) > 1:
            splitting = [axis for axis in self.axes if _changes_shape(self, axis)]
            lines.append(
                f"{len(programs)} separate programs: {', '.join(splitting)} change(s) shapes"
            )
        else:
            lines.append("one program")
        return "\n".join(lines)


def shape_key(config: Config) -> tuple:
    """What fixes a training program's shapes: static env params, network, sizes."""
    env, _ = config.make_env()
    sizes = tuple(config["train"][name] for name in TRAIN_SIZES)
    return (env.static, config.network_config(), sizes)


def _changes_shape(sweep: Sweep, axis: str) -> bool:
    """Whether two points that differ only in ``axis`` have different shapes."""
    seen: dict[tuple, set] = {}
    for p in sweep.points:
        rest = tuple((k, _hashable(v)) for k, v in p.values.items() if k != axis)
        seen.setdefault(rest, set()).add(shape_key(p.config))
    return any(len(keys) > 1 for keys in seen.values())


def _hashable(value: Any) -> Any:
    return tuple(_hashable(v) for v in value) if isinstance(value, list) else value


def _axis_values(name: str, spec: Any) -> list[Any]:
    if isinstance(spec, list):
        if not spec:
            raise ConfigError(f"axes.{name} = []: an axis needs at least one value")
        return spec
    if isinstance(spec, dict):
        unknown = set(spec) - {"start", "stop", "num", "step"}
        if unknown or "start" not in spec or "stop" not in spec:
            raise ConfigError(
                f"axes.{name} = {spec!r}: a range is {{start, stop}} (integers, stop excluded),"
                " {start, stop, step} or {start, stop, num} (num values, ends included)"
            )
        start, stop = spec["start"], spec["stop"]
        if "num" in spec:
            num = spec["num"]
            if not isinstance(num, int) or num < 1:
                raise ConfigError(f"axes.{name}.num = {num!r}: must be an integer >= 1")
            return [float(x) for x in np.linspace(start, stop, num)]
        step = spec.get("step", 1)
        if not all(isinstance(x, int) for x in (start, stop, step)) or step == 0:
            raise ConfigError(
                f"axes.{name} = {spec!r}: start, stop and step must be integers, step != 0"
            )
        values = list(range(start, stop, step))
        if not values:
            raise ConfigError(f"axes.{name} = {spec!r}: the range is empty")
        return values
    raise ConfigError(f"axes.{name} = {spec!r}: must be a list of values or a range table")


def _override(name: str, value: Any) -> str:
    return f"{name}={toml_value(value)}"


def load_sweep(path: str | Path, overrides: Sequence[str] = ()) -> Sweep:
    """Read a sweep file and validate every point's config (nothing compiles).

    Args:
        path: the sweep TOML.
        overrides: ``section.field=value`` applied to every point after ``[set]``.
    Raises:
        ConfigError: naming the sweep key, axis or point field at fault.
    """
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"sweep {str(path)!r}: no such file") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"sweep {str(path)!r}: not valid TOML: {err}") from None
    unknown = set(raw) - {"base", "mode", "set", "axes"}
    if unknown:
        raise ConfigError(
            f"sweep {str(path)!r}: unknown key(s) {', '.join(sorted(unknown))}; "
            "allowed: base, mode, set, axes"
        )
    base = raw.get("base", "default")
    base_path = path.parent / base
    base_source = base_path if base_path.is_file() else base
    mode = raw.get("mode", "product")
    if mode not in MODES:
        raise ConfigError(f"mode = {mode!r}: must be one of {', '.join(map(repr, MODES))}")
    shared = [_override(k, v) for k, v in raw.get("set", {}).items()] + list(overrides)
    axes = {name: _axis_values(name, spec) for name, spec in raw.get("axes", {}).items()}
    for name in axes:
        parse_override(f"{name}=0")  # a well-formed section.field
    if mode == "zip":
        lengths = {name: len(v) for name, v in axes.items()}
        if len(set(lengths.values())) > 1:
            raise ConfigError(f"mode = 'zip' needs axes of one length; got {lengths}")
        combos = list(zip(*axes.values(), strict=True)) if axes else [()]
    else:
        combos = list(itertools.product(*axes.values()))
    points = []
    for i, combo in enumerate(combos):
        values = dict(zip(axes, combo, strict=True))
        point_overrides = shared + [_override(k, v) for k, v in values.items()]
        try:
            config = load_config(base_source, point_overrides)
        except ConfigError as err:
            raise ConfigError(f"sweep point {i} ({values}): {err}") from None
        points.append(SweepPoint(i, values, config))
    return Sweep(str(base), axes, points)


def _stack(trees: Sequence[Any]) -> Any:
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


def _pad(tree: Any, size: int) -> Any:
    """Leading axis padded to ``size`` with copies of the last row."""

    def pad(x):
        n = x.shape[0]
        if n == size:
            return x
        return jax.numpy.concatenate([x, jax.numpy.repeat(x[-1:], size - n, axis=0)])

    return jax.tree.map(pad, tree)


def train_runs(points: Sequence[SweepPoint], devices: Sequence[Any] | None = None):
    """Train ``points`` (all of one shape) in one ``jit(vmap(train))``, sharded.

    Returns:
        ``(trainer, params, metrics)`` with NumPy leaves of leading size
        ``len(points)`` (padding dropped).
    """
    devices = list(jax.devices() if devices is None else devices)
    trainer = make_train(points[0].config.train_config())
    n, d = len(points), len(devices)
    size = math.ceil(n / d) * d
    keys = jax.numpy.stack([p.config.keys()[0] for p in points])
    hparams = _stack([p.config.hyperparams() for p in points])
    env_params = _stack([p.config.make_env()[1] for p in points])
    sharding = NamedSharding(Mesh(np.asarray(devices), ("runs",)), PartitionSpec("runs"))
    args = jax.device_put(_pad((keys, hparams, env_params), size), sharding)
    train = jax.jit(jax.vmap(trainer.train), out_shardings=sharding)
    params, metrics = train(*args)
    params, metrics = jax.tree.map(lambda x: np.asarray(x)[:n], (params, metrics))
    return trainer, params, metrics


def evaluate_runs(
    trainer: Any, params: Any, points: Sequence[SweepPoint], eval_key: jax.Array, episodes: int
) -> list[dict[str, Any]]:
    """SPEC §8 metrics of each run's greedy DRQN on the same ``episodes`` episodes."""
    keys = episode_keys(eval_key, episodes)
    out = []
    for i, point in enumerate(points):
        env, env_params = point.config.make_env()
        agent = drqn_agent(trainer.network, jax.tree.map(lambda x, i=i: x[i], params))
        ep = run_episodes(agent, keys, env, env_params)
        out.append(summarize(jax.tree.map(np.asarray, ep), float(env_params.ttc_threshold)))
    return out


def run_sweep(sweep: Sweep, devices: Sequence[Any] | None = None) -> list[dict[str, Any]]:
    """Train and evaluate every point; one result dict per run, in point order."""
    eval_key = sweep.points[0].config.keys()[1]
    episodes = sweep.points[0].config["evaluate"]["episodes"]
    results: dict[int, dict[str, Any]] = {}
    for points in sweep.programs():
        trainer, params, metrics = train_runs(points, devices)
        evaluations = evaluate_runs(trainer, params, points, eval_key, episodes)
        for i, (point, evaluation) in enumerate(zip(points, evaluations, strict=True)):
            returns = metrics["episode_return"][i]
            tail = max(1, len(returns) // 10)
            results[point.index] = {
                "index": point.index,
                "values": point.values,
                "final_train_return": float(np.mean(returns[-tail:])),
                **evaluation,
            }
    return [results[i] for i in range(len(sweep.points))]


def _interval(values: np.ndarray) -> tuple[float, float]:
    """95 % Student-t interval of the mean (nan with fewer than 2 values)."""
    n = len(values)
    if n < 2:
        return (math.nan, math.nan)
    half = T_975[min(n - 1, len(T_975)) - 1] * values.std(ddof=1) / math.sqrt(n)
    return (float(values.mean() - half), float(values.mean() + half))


def interquartile_mean(values: np.ndarray) -> float:
    """Mean of the middle 50 % (the 25 %-trimmed mean, fractional ends weighted)."""
    x = np.sort(np.asarray(values, np.float64))
    n = len(x)
    lo, hi = 0.25 * n, 0.75 * n
    weights = np.clip(np.minimum(np.arange(1, n + 1), hi) - np.maximum(np.arange(n), lo), 0, 1)
    return float(np.sum(weights * x) / np.sum(weights))


# two-sided 95 % Student-t quantiles for 1..30 degrees of freedom, then the normal's
T_975 = (
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228,
    2.201, 2.179, 2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086,
    2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042, 1.960,
)  # fmt: skip

TABLE_METRICS = (
    "collision_free_rate",
    "goal_rate",
    "avg_speed_kmh",
    "avg_distance_m",
    "avg_return",
    "final_train_return",
)


def summarize_sweep(results: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per setting (axis values but the seed): n runs and, per metric, mean, std,
    95 % t-interval and interquartile mean across the seeds."""
    settings: dict[tuple, list[dict[str, Any]]] = {}
    for r in results:
        key = tuple((k, _hashable(v)) for k, v in r["values"].items() if k != "run.seed")
        settings.setdefault(key, []).append(r)
    rows = []
    for key, runs in settings.items():
        row: dict[str, Any] = {"setting": dict(key), "runs": len(runs)}
        for metric in TABLE_METRICS:
            x = np.array([r[metric] for r in runs], np.float64)
            low, high = _interval(x)
            row[metric] = {
                "mean": float(x.mean()),
                "std": float(x.std(ddof=1)) if len(x) > 1 else math.nan,
                "ci95": (low, high),
                "iqm": interquartile_mean(x),
            }
        rows.append(row)
    return rows


def sweep_table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown: one row per setting, ``mean ± std [95 % CI] (IQM)`` per metric."""
    names = list(rows[0]["setting"]) if rows else []
    header = [*names, "runs", *TABLE_METRICS]
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    for row in rows:
        cells = [str(row["setting"][n]) for n in names] + [str(row["runs"])]
        for metric in TABLE_METRICS:
            m = row[metric]
            low, high = m["ci95"]
            cells.append(
                f"{m['mean']:.3g} ± {m['std']:.2g} [{low:.3g}, {high:.3g}] ({m['iqm']:.3g})"
            )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def sweep_csv(rows: Sequence[dict[str, Any]]) -> str:
    """CSV of :func:`summarize_sweep`: setting columns, runs, then per metric
    ``<metric>_mean``, ``_std``, ``_ci_low``, ``_ci_high``, ``_iqm``."""
    names = list(rows[0]["setting"]) if rows else []
    header = [*names, "runs"]
    for metric in TABLE_METRICS:
        header += [f"{metric}_{s}" for s in ("mean", "std", "ci_low", "ci_high", "iqm")]
    lines = [",".join(header)]
    for row in rows:
        cells = [str(row["setting"][n]) for n in names] + [str(row["runs"])]
        for metric in TABLE_METRICS:
            m = row[metric]
            cells += [repr(m["mean"]), repr(m["std"]), repr(m["ci95"][0]), repr(m["ci95"][1])]
            cells.append(repr(m["iqm"]))
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"
