"""Hyperparameter sweeps (the sweep file: docs/guide.md, "Sweeps"): points whose shapes agree
form one program (``jit(vmap(train))``), every run evaluated on the first point's evaluation
episodes, and the results table. Running: :mod:`drqn_jax.experiments.sweep_runner`."""

import dataclasses
import functools
import itertools
import math
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drqn_jax.config import (
    TRAIN_SIZES,
    Config,
    ConfigError,
    load_config,
    parse_override,
    toml_value,
)
from drqn_jax.experiments.frontier import interquartile_mean, t_interval
from drqn_jax.learners.hyperparams import teachers_of

MODES = ("product", "zip")
#: How a device trains its runs: ``vmap`` (batched, for accelerators), ``map`` (``lax.map``,
#: one after another, for CPUs), ``auto``: ``map`` on CPU, ``vmap`` elsewhere.
STRATEGIES = ("auto", "vmap", "map")


@dataclasses.dataclass(frozen=True)
class SweepPoint:
    """One run: its index in the sweep, axis values and resolved config."""

    index: int
    values: dict[str, Any]
    config: Config

    @functools.cached_property
    def shape(self) -> tuple:
        """What fixes the point's training program's shapes: static env params, network,
        sizes (computed once)."""
        env, _ = self.config.make_env()
        sizes = tuple(self.config["train"][name] for name in TRAIN_SIZES)
        return (env.static, self.config.network_config(), sizes)


@dataclasses.dataclass(frozen=True)
class Sweep:
    """A validated sweep: its points and their grouping into programs."""

    base: str
    axes: dict[str, list[Any]]
    points: list[SweepPoint]
    strategy: str = "auto"

    def programs(self) -> list[list[SweepPoint]]:
        """Points grouped by shapes, in order of first appearance: one program each."""
        groups: dict[Any, list[SweepPoint]] = {}
        for point in self.points:
            groups.setdefault(point.shape, []).append(point)
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


def _changes_shape(sweep: Sweep, axis: str) -> bool:
    """Whether two points that differ only in ``axis`` have different shapes."""
    seen: dict[tuple, set] = {}
    for p in sweep.points:
        rest = tuple((k, _hashable(v)) for k, v in p.values.items() if k != axis)
        seen.setdefault(rest, set()).add(p.shape)
    return any(len(keys) > 1 for keys in seen.values())


def _hashable(value: Any) -> Any:
    return tuple(_hashable(v) for v in value) if isinstance(value, list) else value


def _axis_values(name: str, spec: Any) -> list[Any]:
    """An axis's values from a list or a range table ``{start, stop[, step | num]}``."""
    values = spec
    if isinstance(spec, dict):
        start, stop, num, step = (spec.get(k) for k in ("start", "stop", "num", "step"))
        if set(spec) - {"start", "stop", "num", "step"} or start is None or stop is None:
            raise ConfigError(
                f"axes.{name} = {spec!r}: a range is {{start, stop}} (integers, stop excluded),"
                " {start, stop, step} or {start, stop, num} (num values, ends included)"
            )
        if num is not None:
            if not isinstance(num, int) or num < 1:
                raise ConfigError(f"axes.{name}.num = {num!r}: must be an integer >= 1")
            return [float(x) for x in np.linspace(start, stop, num)]
        step = 1 if step is None else step
        if not all(isinstance(x, int) for x in (start, stop, step)) or step == 0:
            raise ConfigError(
                f"axes.{name} = {spec!r}: start, stop and step must be integers, step != 0"
            )
        values = list(range(start, stop, step))
    if not isinstance(values, list):
        raise ConfigError(f"axes.{name} = {spec!r}: must be a list of values or a range table")
    if not values:
        raise ConfigError(f"axes.{name} = {spec!r}: an axis needs at least one value")
    return values


def load_sweep(path: str | Path, overrides: Sequence[str] = ()) -> Sweep:
    """Read a sweep TOML and validate every point (``overrides`` after ``[set]``); ConfigError."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"sweep {str(path)!r}: no such file") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"sweep {str(path)!r}: not valid TOML: {err}") from None
    unknown = set(raw) - {"base", "mode", "strategy", "set", "axes"}
    if unknown:
        raise ConfigError(
            f"sweep {str(path)!r}: unknown key(s) {', '.join(sorted(unknown))}; "
            "allowed: base, mode, strategy, set, axes"
        )
    base = raw.get("base", "default")
    base_path = path.parent / base
    shared = [f"{k}={toml_value(v)}" for k, v in raw.get("set", {}).items()] + list(overrides)
    return build_sweep(
        base,
        raw.get("axes", {}),
        shared,
        mode=raw.get("mode", "product"),
        strategy=raw.get("strategy", "auto"),
        base_source=base_path if base_path.is_file() else base,
    )


def build_sweep(
    base: str,
    axes: dict[str, Any],
    overrides: Sequence[str] = (),
    *,
    mode: str = "product",
    strategy: str = "auto",
    base_source: str | Path | None = None,
) -> Sweep:
    """A sweep from a sweep file's parts (``axes``: ``{"section.field": list | range}``);
    raises ConfigError naming the key at fault."""
    for key, value, allowed in (("strategy", strategy, STRATEGIES), ("mode", mode, MODES)):
        if value not in allowed:
            raise ConfigError(f"{key} = {value!r}: must be one of {', '.join(map(repr, allowed))}")
    axes = {name: _axis_values(name, spec) for name, spec in axes.items()}
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
        point_overrides = [*overrides, *(f"{k}={toml_value(v)}" for k, v in values.items())]
        try:
            config = load_config(base if base_source is None else base_source, point_overrides)
        except ConfigError as err:
            raise ConfigError(f"sweep point {i} ({values}): {err}") from None
        points.append(SweepPoint(i, values, config))
    return Sweep(str(base), axes, points, strategy)


TABLE_METRICS = (
    "collision_free_rate",
    "struck_while_stopped_rate",
    "goal_rate",
    "avg_speed_kmh",
    "avg_speed_authors_kmh",
    "avg_distance_m",
    "avg_return",
    "final_train_return",
)


def budget_warnings(points: Sequence[SweepPoint], results: Sequence[dict[str, Any]]) -> list[str]:
    """One line per step-budget run that its episode cap ended first."""
    lines = []
    for point, result in zip(points, results, strict=True):
        train = point.config["train"]
        budget, steps = train["num_env_steps"], result["env_steps"]
        if budget and steps < budget and not result["diverged"]:
            lines.append(
                f"warning: run {point.index} ended at train.num_episodes = "
                f"{train['num_episodes']} after {steps:,} of its {budget:,} env steps: "
                "raise train.num_episodes to train on the whole step budget"
            )
    return lines


def summarize_sweep(results: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per setting (all axes but the seed): runs, diverged, and per metric mean, std, 95 %
    t-interval and IQM across seeds."""
    settings: dict[tuple, list[dict[str, Any]]] = {}
    for r in results:
        key = tuple((k, _hashable(v)) for k, v in r["values"].items() if k != "run.seed")
        settings.setdefault(key, []).append(r)
    rows = []
    for key, runs in settings.items():
        diverged = sum(bool(r["diverged"]) for r in runs)
        row: dict[str, Any] = {"setting": dict(key), "runs": len(runs), "diverged": diverged}
        row["teacher"] = teachers_of(runs)
        for metric in TABLE_METRICS:
            x = np.array([r[metric] for r in runs], np.float64)  # None: non-finite, in JSON
            low, high = t_interval(x)
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
    header = [*names, "runs", "teacher", *TABLE_METRICS]
    table = [header, ["---"] * len(header)]
    for row in rows:
        runs = f"{row['runs']}" + (f" ({row['diverged']} diverged)" if row["diverged"] else "")
        cells = [str(row["setting"][n]) for n in names] + [runs, row["teacher"]]
        for m in (row[metric] for metric in TABLE_METRICS):
            low, high = m["ci95"]
            cells.append(
                f"{m['mean']:.3g} ± {m['std']:.2g} [{low:.3g}, {high:.3g}] ({m['iqm']:.3g})"
            )
        table.append(cells)
    return "\n".join("| " + " | ".join(cells) + " |" for cells in table)


def sweep_csv(rows: Sequence[dict[str, Any]]) -> str:
    """CSV of :func:`summarize_sweep`: per metric ``_mean``, ``_std``, ``_ci_*``, ``_iqm``."""
    names = list(rows[0]["setting"]) if rows else []
    header = [*names, "runs", "diverged"]
    for metric in TABLE_METRICS:
        header += [f"{metric}_{s}" for s in ("mean", "std", "ci_low", "ci_high", "iqm")]
    lines = [",".join(header)]
    for row in rows:
        cells = [str(row["setting"][n]) for n in names] + [str(row["runs"]), str(row["diverged"])]
        for m in (row[metric] for metric in TABLE_METRICS):
            cells += [repr(x) for x in (m["mean"], m["std"], *m["ci95"], m["iqm"])]
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"
