"""A study: configs × seeds, each evaluated greedily, beside the rule-based agent.

The paper compared one DRQN with the rule-based agent on 10 episodes each
(Table III) and plotted one training run ("Training performance", §V-F).
A study trains every config for several seeds and evaluates every agent on
the same episodes (the evaluation key of the first seed), so that the rows
differ only by the agent::

    drqn-jax study --configs paper,default,dqn --seeds 5 --episodes 1000 --out studies/table3

Each config is a sweep over ``run.seed`` (:mod:`drqn_jax.experiments.sweep`) in
``OUT/<config>/``: one program per config, run by
:func:`~drqn_jax.experiments.sweep_runner.run_sweep` with its checkpoints, so an
interrupted study continues where it stopped when the same command runs again.
The rule-based agent is evaluated once per distinct ``[env]`` section on the
same episodes, and so is its family's frontier (SPEC §9,
:mod:`drqn_jax.experiments.frontier`; the privileged planner's too, in the first
config's world). Then:

* ``OUT/study.md``: the paper's rows beside ours (:mod:`drqn_jax.experiments.rows`,
  :func:`~drqn_jax.experiments.report.study_table`) — collision-free % with a 95 %
  interval (across seeds: Student t; a single policy: Wilson over its
  episodes), the margin to the rule-based frontier at the agent's own speed,
  average speed, distance (all and collision-free), goal %, collisions per km, and
  under them the sentences of :mod:`drqn_jax.experiments.verdicts` (each row against
  the frontier, the paper's claim, Table III at scale's goal, arms paired by seed);
* ``OUT/study.json``: the rows, every run's evaluation and the frontiers;
* ``OUT/safety_speed.png``: collision-free rate against average speed, the
  frontiers and every agent (:func:`~drqn_jax.experiments.figures.plot_safety_speed`);
* with ``--eval-envs``: every config's trained agents
  (``OUT/<config>/agents/run-NNNN``) evaluated among other envs' pedestrians
  too, on the same episodes, one row per env (``<config> on <env id>``) beside
  that env's rule-based agent (cached in ``OUT/<config>/cross/<env id>/``);
* ``OUT/curves.png`` and ``OUT/curves.rrd``: average reward and steps per episode
  against env steps, mean and min–max over seeds, as the paper's figure.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from drqn_jax.config import Config, ConfigError, load_config
from drqn_jax.experiments.baselines import (
    cross_results,
    frontier_key,
    frontier_results,
    rule_based_results,
)
from drqn_jax.experiments.checkpoint import atomic_write_text
from drqn_jax.experiments.curves import load_curves, plot_curves
from drqn_jax.experiments.figures import plot_safety_speed
from drqn_jax.experiments.frontier import with_margin
from drqn_jax.experiments.report import strict_json, study_table
from drqn_jax.experiments.rows import baseline_row, paper_rows, study_row
from drqn_jax.experiments.sweep import Sweep, build_sweep
from drqn_jax.experiments.verdicts import study_comparisons
from drqn_jax.learners.hyperparams import agent_name
from drqn_jax.registry import registered_envs

__all__ = ["Arm", "StudyOutcome", "plan_study", "run_study"]


@dataclasses.dataclass(frozen=True)
class Arm:
    """One row of the study: a config trained for every seed (a sweep over ``run.seed``),
    and one more row per env of ``cross_envs``, where its trained agents are evaluated
    as well (among other pedestrians, on the same episodes)."""

    name: str
    sweep: Sweep
    cross_envs: tuple[str, ...] = ()

    @property
    def config(self) -> Config:
        """The first seed's resolved config (the others differ only in ``run.seed``)."""
        return self.sweep.points[0].config

    def cross_config(self, env_id: str) -> Config:
        """:attr:`config` with ``env.id = env_id`` (its preset follows): the evaluation
        among ``env_id``'s pedestrians; the agent stays the one trained with :attr:`config`."""
        return load_config(self.config.values, [f"env.id={env_id}"])


def plan_study(
    configs: Sequence[str],
    seeds: int,
    episodes: int,
    overrides: Sequence[str] = (),
    eval_envs: Sequence[str] = (),
) -> list[Arm]:
    """Validate the study before anything compiles: one :class:`Arm` per config.

    Args:
        configs: config names in ``configs/`` or TOML paths (row names: the file stem).
        seeds: seeds ``0 … seeds − 1`` per config.
        episodes: greedy evaluation episodes per run (the same for every agent).
        overrides: ``section.field=value`` applied to every config.
        eval_envs: env ids every config's agents are evaluated on as well as their
            own (a config's own id among them adds nothing): trained on one kind of
            pedestrians, tested on another.
    Raises:
        ConfigError: a bad count, a duplicate name, an unknown env id, or a config
            field at fault.
    """
    unknown = [e for e in eval_envs if e not in registered_envs()]
    if unknown:
        raise ConfigError(
            f"--eval-envs {unknown[0]!r}: must be one of {', '.join(registered_envs())}"
        )
    if not isinstance(seeds, int) or seeds < 1:
        raise ConfigError(f"--seeds {seeds!r}: must be an integer >= 1")
    if not isinstance(episodes, int) or episodes < 1:
        raise ConfigError(f"--episodes {episodes!r}: must be an integer >= 1")
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


# ----------------------------------------------------------------------------- how runs trained

_TRAINING_FACTS = ("env_steps", "trained_on")


def _training_facts(
    runs: Sequence[Mapping[str, Any]], timings: Mapping[int, float | None]
) -> dict[int, dict[str, Any]]:
    """By run index: how each run trained (env steps, device: from its record; its wall
    time: kept apart from the records, :func:`~drqn_jax.experiments.sweep_outputs.run_timings`),
    for its rows in every world it is evaluated in."""
    return {
        r["index"]: {
            **{k: r[k] for k in _TRAINING_FACTS if k in r},
            "train_wall_s": timings.get(r["index"]),
        }
        for r in runs
    }


# ----------------------------------------------------------------------------- running it


@dataclasses.dataclass
class StudyOutcome:
    """``finished`` (``rows``: the table; ``runs``: config → its runs' results;
    ``comparisons``: each trained row against its world's rule-based frontier;
    ``frontiers``: each world's :func:`~drqn_jax.experiments.frontier.world_frontier`
    record, by :func:`~drqn_jax.experiments.baselines.frontier_key`) or ``interrupted``
    (checkpoints saved; the same command continues). ``continued``: some runs were
    trained, wholly or in part, by an earlier invocation (or not at all here: a report
    only), so this one's wall time does not cover them. ``finished_runs``: on
    interruption, each arm's finished runs as a runs store keeps them
    (:func:`~drqn_jax.experiments.portable.portable_runs`)."""

    status: str
    rows: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    runs: dict[str, list[dict[str, Any]]] = dataclasses.field(default_factory=dict)
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
    """Train and evaluate every arm (continuing a study already in ``out``), evaluate
    the rule-based agent, and write the table and the curves (module docstring).

    With ``train=False`` nothing trains: the report covers the runs that have
    finished so far (a config with none is left out), e.g. of a long study
    interrupted to go on later. ``carried``: arm name → finished runs an interrupted
    study kept in its runs store, written back into an arm's directory that holds
    no sweep yet (:func:`~drqn_jax.experiments.portable.restore_runs`), so that only
    the other runs train; where the directory holds the same runs otherwise, its own
    are kept and a line says which. ``keep``: called with every arm's finished runs (as
    ``finished_runs`` of :class:`StudyOutcome`) each time one more run has finished, so
    that a study whose machine is shut down without warning loses at most the run in
    progress.
    """
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
    if done:
        _write_figures(out, done, runs, rows, frontiers, smooth, png)
    return StudyOutcome("finished", rows, runs, table, comparisons, continued, frontiers)


def _train_arms(
    arms: Sequence[Arm],
    out: Path,
    quiet: bool,
    train: bool,
    carried: Mapping[str, Sequence[Mapping[str, Any]]] | None,
    keep: Callable[[dict[str, list[dict[str, Any]]]], None] | None,
) -> tuple[dict[str, list[dict[str, Any]]], bool] | StudyOutcome:
    """Each arm's finished runs (training what is left when ``train``) and whether a
    sweep continued an earlier invocation's; an interrupted sweep's
    :class:`StudyOutcome` instead (:func:`run_study`'s arguments)."""
    from drqn_jax.experiments.portable import differing_runs, portable_runs, restore_runs
    from drqn_jax.experiments.sweep_outputs import finished_results
    from drqn_jax.experiments.sweep_runner import run_sweep

    runs: dict[str, list[dict[str, Any]]] = {}
    continued = not train

    def finished_runs() -> dict[str, list[dict[str, Any]]]:
        found = {a.name: portable_runs(out / a.name, a.sweep) for a in arms}
        return {name: kept for name, kept in found.items() if kept}

    for arm in arms:
        directory = out / arm.name
        stored = (carried or {}).get(arm.name, ())
        restored = restore_runs(directory, arm.sweep, stored)
        if restored and not quiet:
            print(f"{arm.name}: {restored} finished run(s) from the runs store", file=sys.stderr)
        changed = [] if restored or not stored else differing_runs(directory, arm.sweep, stored)
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
    """The table's rows (the paper's, each finished arm's and its cross-env rows, each
    world's rule-based agent, all with their margins), the trained rows with the
    config each was evaluated on, the cross-env evaluations and the frontiers."""
    from drqn_jax.experiments.sweep_outputs import run_timings

    cross_configs = {a.name: {e: a.cross_config(e) for e in a.cross_envs} for a in done}
    cross = {
        arm.name: {
            env: cross_results(arm.name, config, runs[arm.name], out)
            for env, config in cross_configs[arm.name].items()
        }
        for arm in done
    }
    configs = [a.config for a in arms] + [c for cs in cross_configs.values() for c in cs.values()]
    frontiers = frontier_results(
        configs, out, {frontier_key(done[0].config)} if done else set(), quiet=quiet
    )
    baselines = {
        key: with_margin(
            baseline_row(f"drqn_jax: {c['env']['id']}", r, world=c["env"]["id"]),
            frontiers[frontier_key(c)],
            c.speed_limit_kmh(),
        )
        for key, (c, r) in rule_based_results(configs, out).items()
    }
    trained: list[tuple[dict[str, Any], Config]] = []  # each row and the config it was evaluated on
    for arm in done:
        agent = agent_name(arm.config.train_config())
        evaluated = [(arm.name, arm.config, runs[arm.name])]
        evaluated += [
            (f"{arm.name} on {env}", cross_configs[arm.name][env], results)
            for env, results in cross[arm.name].items()
        ]
        training = _training_facts(runs[arm.name], run_timings(out / arm.name))
        for name, config, results in evaluated:  # a cross row evaluates the arm's agents
            trained_runs = [{**r, **training[r["index"]]} for r in results]
            row = study_row(f"drqn_jax: {name}", agent, trained_runs, world=config["env"]["id"])
            margin = with_margin(row, frontiers[frontier_key(config)], config.speed_limit_kmh())
            trained.append((margin, config))
    # configs that differ only in what the rule-based agent ignores (the reward) share its row
    shown = {json.dumps(strict_json(r), sort_keys=True): r for r in baselines.values()}
    rows = [*paper_rows(), *(row for row, _ in trained), *shown.values()]
    return rows, trained, cross, frontiers


def _write_figures(
    out: Path,
    done: Sequence[Arm],
    runs: Mapping[str, list[dict[str, Any]]],
    rows: Sequence[Mapping[str, Any]],
    frontiers: Mapping[str, Any],
    smooth: int,
    png: bool,
) -> None:
    """``OUT/curves.rrd`` and, with ``png``, ``OUT/curves.png`` and
    ``OUT/safety_speed.png`` (module docstring)."""
    from drqn_jax.experiments.sweep_outputs import metrics_path
    from drqn_jax.interop.training_recording import record_study_curves

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
