"""A study (paper Table III, §V-F; SPEC §9; usage: docs/guide.md, "The reproduction study"):
configs × seeds, each config a resumable sweep over ``run.seed`` in ``OUT/<config>/``, evaluated
greedily on the same episodes beside the rule-based agent and its frontier. Writes ``OUT/study.md``
(rows, 95 % intervals, frontier margins, verdicts), ``study.json``, ``safety_speed.png``,
``curves.png``/``.rrd``. A runs store (:func:`_portable_runs`: ``{"command": ..., "finished_runs":
{arm: [run, ...]}}``) keeps the finished runs apart from ``OUT``, so a study outlives its directory:
restored runs give the same table bit for bit, but have no agent."""

import dataclasses
import json
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jax

from drqn_jax.config import Config, ConfigError, load_config
from drqn_jax.experiments.baselines import (
    cross_results,
    frontier_key,
    frontier_results,
    rule_based_results,
)
from drqn_jax.experiments.checkpoint import atomic_write_text
from drqn_jax.experiments.curves import load_curves, plot_curves, plot_safety_speed
from drqn_jax.experiments.frontier import with_margin
from drqn_jax.experiments.report import strict_json, study_table
from drqn_jax.experiments.rows import baseline_row, paper_rows, study_row
from drqn_jax.experiments.sweep import Sweep, build_sweep
from drqn_jax.experiments.sweep_outputs import (
    finished_results,
    metrics_path,
    open_plan,
    run_timings,
    write_call,
)
from drqn_jax.experiments.sweep_plan import Distributed, plan_calls
from drqn_jax.experiments.verdicts import study_comparisons
from drqn_jax.interop.recording import record_study_curves
from drqn_jax.learners.hyperparams import agent_name
from drqn_jax.registry import registered_envs


@dataclasses.dataclass(frozen=True)
class Arm:
    """One row: a config trained for every seed, plus one row per env of ``cross_envs``."""

    name: str
    sweep: Sweep
    cross_envs: tuple[str, ...] = ()

    @property
    def config(self) -> Config:
        """The first seed's resolved config (the others differ only in ``run.seed``)."""
        return self.sweep.points[0].config


def plan_study(
    configs: Sequence[str],
    seeds: int,
    episodes: int,
    overrides: Sequence[str] = (),
    eval_envs: Sequence[str] = (),
) -> list[Arm]:
    """Validate the study before anything compiles: one :class:`Arm` per config (``configs``:
    names or TOML paths; ``seeds``: 0 … seeds − 1; ``eval_envs``: env ids the agents are also
    evaluated on). Raises ConfigError."""
    unknown = [e for e in eval_envs if e not in registered_envs()]
    if unknown:
        raise ConfigError(
            f"--eval-envs {unknown[0]!r}: must be one of {', '.join(registered_envs())}"
        )
    for option, count in (("--seeds", seeds), ("--episodes", episodes)):
        if not isinstance(count, int) or count < 1:
            raise ConfigError(f"{option} {count!r}: must be an integer >= 1")
    names = [Path(c).stem for c in configs]
    if not names:
        raise ConfigError("--configs: name at least one config")
    if len(set(names)) < len(names):
        raise ConfigError(f"--configs {','.join(configs)}: two configs share a name")
    shared = [*overrides, f"evaluate.episodes={episodes}"]
    arms = []
    for name, config in zip(names, configs, strict=True):
        sweep = build_sweep(config, {"run.seed": list(range(seeds))}, shared)
        own = sweep.points[0].config["env"]["id"]
        cross = tuple(dict.fromkeys(e for e in eval_envs if e != own))
        arms.append(Arm(name, sweep, cross))
    return arms


@dataclasses.dataclass
class StudyOutcome:
    """``finished`` (rows, comparisons to frontiers, frontiers) or ``interrupted``
    (``finished_runs``: each arm's, for a runs store). ``continued``: an earlier invocation
    trained some runs, so this wall time does not cover them."""

    status: str
    rows: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    table: str = ""
    comparisons: list[str] = dataclasses.field(default_factory=list)
    continued: bool = False
    frontiers: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    finished_runs: dict[str, list[dict[str, Any]]] = dataclasses.field(default_factory=dict)


def run_study(
    arms: Sequence[Arm],
    out: str | Path,
    *,
    smooth: int = 10,
    png: bool = True,
    quiet: bool = False,
    train: bool = True,
    carried: Mapping[str, Sequence[Mapping[str, Any]]] | None = None,
    keep: Callable[[dict[str, list[dict[str, Any]]]], None] | None = None,
) -> StudyOutcome:
    """Train and evaluate every arm (continuing ``out``) and the rule-based agent; write the
    table and curves. ``train=False``: report the finished runs only; ``carried``: arm → runs
    restored from a runs store; ``keep``: called with all finished runs after each run finishes."""
    out = Path(out)
    trained_runs = _train_arms(arms, out, quiet, train, carried, keep)
    if isinstance(trained_runs, StudyOutcome):
        return trained_runs
    runs, continued = trained_runs
    done = [arm for arm in arms if runs[arm.name]]
    rows, trained, cross, frontiers = _study_rows(arms, done, runs, out, quiet)
    comparisons = study_comparisons(trained, [a.name for a in done], runs, frontiers)
    table = study_table(rows, comparisons)
    atomic_write_text(out / "study.md", table + "\n")
    record = {"rows": rows, "comparisons": comparisons, "runs": runs, "cross": cross}
    record = strict_json({**record, "smooth": smooth, "frontiers": frontiers})
    atomic_write_text(out / "study.json", json.dumps(record, indent=1) + "\n")
    if done:  # OUT/curves.rrd and, with png, curves.png and safety_speed.png
        curves = {
            arm.name: load_curves(
                [metrics_path(out / arm.name, r["index"]) for r in runs[arm.name]], smooth
            )
            for arm in done
        }
        record_study_curves(out / "curves.rrd", curves)
        if png:
            plot_curves(curves, out / "curves.png", smooth)
            first = frontiers[frontier_key(done[0].config)]
            plot_safety_speed(rows, first, out / "safety_speed.png")
    return StudyOutcome("finished", rows, table, comparisons, continued, frontiers)


def _train_arms(
    arms: Sequence[Arm],
    out: Path,
    quiet: bool,
    train: bool,
    carried: Mapping[str, Sequence[Mapping[str, Any]]] | None,
    keep: Callable[[dict[str, list[dict[str, Any]]]], None] | None,
) -> tuple[dict[str, list[dict[str, Any]]], bool] | StudyOutcome:
    """Each arm's finished runs and whether any continued; or an interrupted outcome."""
    from drqn_jax.experiments.sweep_runner import run_sweep  # looked up here: tests replace it

    runs: dict[str, list[dict[str, Any]]] = {}
    continued = not train

    def finished_runs() -> dict[str, list[dict[str, Any]]]:
        found = {a.name: _portable_runs(out / a.name, a.sweep) for a in arms}
        return {name: kept for name, kept in found.items() if kept}

    for arm in arms:
        directory = out / arm.name
        stored = (carried or {}).get(arm.name, ())
        restored = _restore_runs(directory, arm.sweep, stored)
        if restored and not quiet:
            print(f"{arm.name}: {restored} finished run(s) from the runs store", file=sys.stderr)
        changed = [] if restored or not stored else _differing_runs(directory, arm.sweep, stored)
        if changed:
            print(
                f"{arm.name}: run(s) {changed} in {directory} differ from the runs store's "
                f"records; the directory's are kept (remove {directory} to use the store's)",
                file=sys.stderr,
            )
        if not train:
            runs[arm.name] = finished_results(directory)
            continue
        resume = (directory / "plan.json").is_file()
        outcome = run_sweep(
            arm.sweep,
            directory,
            resume=resume,
            quiet=quiet,
            on_call_finished=None if keep is None else lambda: keep(finished_runs()),
        )
        if outcome.status == "interrupted":
            return StudyOutcome("interrupted", finished_runs=finished_runs())
        runs[arm.name] = outcome.results
        continued = continued or outcome.continued > 0
    return runs, continued


def _study_rows(
    arms: Sequence[Arm],
    done: Sequence[Arm],
    runs: Mapping[str, list[dict[str, Any]]],
    out: Path,
    quiet: bool,
) -> tuple[list[dict[str, Any]], list[tuple[dict[str, Any], Config]], dict, dict]:
    """The rows (paper, arms, cross-env, rule-based, with margins), the trained rows' configs,
    the cross-env evaluations and the frontiers."""
    cross_configs = {  # each arm's config among another env's pedestrians
        a.name: {e: load_config(a.config.values, [f"env.id={e}"]) for e in a.cross_envs}
        for a in done
    }
    cross = {
        name: {env: cross_results(name, c, runs[name], out) for env, c in configs.items()}
        for name, configs in cross_configs.items()
    }
    configs = [a.config for a in arms] + [c for cs in cross_configs.values() for c in cs.values()]
    frontiers = frontier_results(
        configs, out, {frontier_key(done[0].config)} if done else set(), quiet=quiet
    )

    def judged(row: dict[str, Any], config: Config) -> dict[str, Any]:
        return with_margin(row, frontiers[frontier_key(config)], config.speed_limit_kmh())

    baselines = [
        judged(baseline_row(f"drqn_jax: {c['env']['id']}", r, world=c["env"]["id"]), c)
        for c, r in rule_based_results(configs, out).values()
    ]
    trained: list[tuple[dict[str, Any], Config]] = []  # each row and the config it was evaluated on
    for arm in done:
        agent = agent_name(arm.config.train_config())
        evaluated = [(arm.name, arm.config, runs[arm.name])]
        evaluated += [
            (f"{arm.name} on {env}", cross_configs[arm.name][env], results)
            for env, results in cross[arm.name].items()
        ]
        timings = run_timings(out / arm.name)
        training = {  # how each run trained: env steps, device, wall time
            r["index"]: {
                **{k: r[k] for k in ("env_steps", "trained_on") if k in r},
                "train_wall_s": timings.get(r["index"]),
            }
            for r in runs[arm.name]
        }
        for name, config, results in evaluated:  # a cross row evaluates the arm's agents
            trained_runs = [{**r, **training[r["index"]]} for r in results]
            row = study_row(
                f"drqn_jax: {name}",
                agent,
                trained_runs,
                world=config["env"]["id"],
                decision_steps=config["env"]["decision_steps"],
            )
            trained.append((judged(row, config), config))
    # configs that differ only in what the rule-based agent ignores (the reward) share its row
    shown = {json.dumps(strict_json(r), sort_keys=True): r for r in baselines}
    rows = [*paper_rows(), *(row for row, _ in trained), *shown.values()]
    return rows, trained, cross, frontiers


def _portable_runs(directory: Path, sweep: Sweep) -> list[dict[str, Any]]:
    """By index, the finished runs of ``sweep`` in ``directory``: record, training hash,
    ``train_wall_s`` and ``metrics.csv`` text (runs without metrics left out)."""
    hashes = {p.index: p.config.training_hash() for p in sweep.points}
    timings = run_timings(directory)
    runs = []
    for record in finished_results(directory):
        metrics = metrics_path(directory, record["index"])
        if record["index"] not in hashes or not metrics.is_file():
            continue
        runs.append(
            {
                **record,
                "training_hash": hashes[record["index"]],
                "train_wall_s": timings.get(record["index"]),
                "metrics_csv": metrics.read_text(),
            }
        )
    return runs


def _restore_runs(directory: Path, sweep: Sweep, stored: Sequence[Mapping[str, Any]]) -> int:
    """Write ``stored`` runs back into an empty ``directory`` as finished calls of ``sweep``'s
    plan (matching index, training hash and episode count; whole calls only); returns the
    number restored."""
    if (directory / "plan.json").exists() or not stored:
        return 0
    points = {p.index: p for p in sweep.points}
    usable = {
        run["index"]: run
        for run in stored
        if (point := points.get(run.get("index"))) is not None
        and run.get("training_hash") == point.config.training_hash()
        and run.get("num_episodes") == point.config["evaluate"]["episodes"]
    }
    calls = plan_calls(sweep, len(jax.local_devices()))
    restored = [c for c in calls if all(p.index in usable for p in c.points)]
    if not restored:
        return 0
    open_plan(directory, sweep, Distributed(), resume=False)
    for call in restored:
        runs = [usable[p.index] for p in call.points]
        apart = ("metrics_csv", "train_wall_s")
        saved = [{k: v for k, v in run.items() if k not in apart} for run in runs]
        walls = [run.get("train_wall_s") for run in runs]
        wall = None if None in walls else sum(walls)
        write_call(directory, call, saved, [run["metrics_csv"] for run in runs], wall)
    return sum(len(c.points) for c in restored)


def _differing_runs(
    directory: Path, sweep: Sweep, stored: Sequence[Mapping[str, Any]]
) -> list[int]:
    """Indices of finished runs in ``directory`` whose record differs from ``stored``'s (the
    directory's win; the study says so)."""
    kept = {run.get("index"): run for run in stored}
    return [
        run["index"]
        for run in _portable_runs(directory, sweep)
        if run["index"] in kept
        and kept[run["index"]].get("training_hash") == run["training_hash"]
        and kept[run["index"]] != run
    ]
