"""What every arm of a study is judged against (SPEC §9), per world, cached in ``OUT/baselines/``:
the rule-based agent, its frontier, the planner's, and cross-env replays. Worlds are keyed by
digests of what each result reads (:func:`env_key`, :func:`frontier_key`), so configs differing
elsewhere share one sweep."""

import hashlib
import json
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from drqn_jax.config import Config
from drqn_jax.experiments.checkpoint import CheckpointError, atomic_write_text
from drqn_jax.experiments.frontier import world_frontier
from drqn_jax.learners.hyperparams import agent_name


def _digest(config: Config, **sections: Any) -> str:
    """A short digest of ``sections`` and ``config``'s evaluation episodes (count, seed)."""
    record = {**sections, "episodes": config["evaluate"]["episodes"], "seed": config["run"]["seed"]}
    text = json.dumps(record, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def _yardstick_env(config: Config) -> dict[str, Any]:
    """``[env]`` as the yardstick plays it: it decides at every tick (SPEC §9), so the
    decision interval and how a setpoint moves over a decision do not change it."""
    return {
        k: v for k, v in config["env"].items() if k not in ("decision_steps", "setpoint_change")
    }


def env_key(config: Config) -> str:
    """Digest of ``[env]``, ``[rule_based]`` and the evaluation episodes: the baseline's key."""
    return _digest(config, env=_yardstick_env(config), rule_based=config["rule_based"])


def frontier_key(config: Config) -> str:
    """Digest of ``[env]`` without ``reward_*``, ``[planner]`` and the evaluation episodes:
    configs that agree share frontiers, and their arms are paired."""
    env = {k: v for k, v in _yardstick_env(config).items() if not k.startswith("reward_")}
    return _digest(config, env=env, planner=config["planner"])


def rule_based_results(
    configs: Sequence[Config], out: Path
) -> dict[str, tuple[Config, dict[str, Any]]]:
    """``{env_key: (first config, result)}``: the rule-based agent on each distinct env of
    ``configs`` (and their ``cross_envs``), cached in ``OUT/baselines/``."""
    from drqn_jax.experiments.runner import builtin_agent, evaluate_agents, json_ready

    def evaluated(config: Config) -> dict[str, Any]:
        (result,) = evaluate_agents(config, [builtin_agent("rule-based", config)])
        return json_ready(result)

    found: dict[str, tuple[Config, dict[str, Any]]] = {}
    for config in configs:
        key = env_key(config)
        if key not in found:
            path = out / "baselines" / f"rule-based-{key}.json"
            found[key] = (config, _cached(path, evaluated, config))
    return found


def _cached(path: Path, compute: Callable[..., dict[str, Any]], *args: Any, **kw: Any) -> Any:
    """The JSON at ``path``, or ``compute(*args, **kw)``, then written there (atomically)."""
    if path.is_file():
        return json.loads(path.read_text())
    result = compute(*args, **kw)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(result, indent=1) + "\n")
    return result


def cross_results(
    arm: str, config: Config, runs: Sequence[Mapping[str, Any]], out: Path
) -> list[dict[str, Any]]:
    """Each of ``runs``' agents evaluated with ``config`` (among ``env_id``'s pedestrians),
    cached in ``OUT/<arm>/cross/<env_id>/``; CheckpointError if an agent is missing."""
    from drqn_jax.agents import drqn_agent
    from drqn_jax.experiments.runner import (
        evaluate_agents,
        json_ready,
        load_run,
        load_trained_network,
    )
    from drqn_jax.experiments.sweep_outputs import agent_dir

    env_id = config["env"]["id"]

    def evaluated(run: Mapping[str, Any]) -> dict[str, Any]:
        directory = agent_dir(out / arm, run["index"])
        if not (directory / "config.toml").is_file():
            raise CheckpointError(
                f"{directory}: no trained agent to evaluate on {env_id} (a run restored "
                "from a runs store keeps none); run the study in a new --out"
            )
        trained = load_run(directory)
        network, params, _ = load_trained_network(trained, directory)
        name = agent_name(trained.train_config())
        (result,) = evaluate_agents(config, [drqn_agent(network, params, name)])
        return {"index": run["index"], "values": run["values"], **json_ready(result)}

    cache = out / arm / "cross" / env_id
    return [_cached(cache / f"run-{run['index']:04d}.json", evaluated, run) for run in runs]


def frontier_results(
    configs: Sequence[Config], out: Path, planner_keys: set[str], *, quiet: bool = True
) -> dict[str, dict[str, Any]]:
    """``{frontier_key: world_frontier record}`` per distinct env of ``configs`` (with the
    planner's where in ``planner_keys``), cached in ``OUT/baselines/``."""
    found: dict[str, dict[str, Any]] = {}
    for config in configs:
        key = frontier_key(config)
        if key in found:
            continue
        if not quiet:
            print(f"the frontiers of {config['env']['id']}...", file=sys.stderr, flush=True)
        planner = key in planner_keys
        path = out / "baselines" / f"frontier-{key}{'-planner' if planner else ''}.json"
        found[key] = _cached(path, config_frontier, config, planner=planner)
    return found


def config_frontier(config: Config, *, planner: bool = True, **options: Any) -> dict[str, Any]:
    """:func:`~drqn_jax.experiments.frontier.world_frontier` on ``config``'s world, evaluation
    episodes and ``[planner]``."""
    env, params = config.make_env()
    _, key = config.keys()
    return world_frontier(
        env,
        params,
        key,
        config["evaluate"]["episodes"],
        world=config["env"]["id"],
        seed=config["run"]["seed"],
        planner=config.planner_params() if planner else None,
        **options,
    )
