"""The protocol every learner (dqn, ppo, pqn) serves: a :class:`Trainer` of pure
functions, all the host loop, sweeps, checkpoints and evaluation use. Every state has
``key``, ``hparams``, ``env_params``, ``online``, ``opt_state``, ``recorded``,
``finished``, ``env_steps``, ``grad_steps``, ``ep_loss_sum``, ``metrics``, ``validation``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax

from drqn_jax.learners.selection import candidate_metrics, run_agent

__all__ = ["Trainer", "make_trainer"]


class Trainer(NamedTuple):
    """The pure functions of one training configuration: ``init``, ``act`` (actions
    (N,), carry), ``run(state, n)`` (no-ops once finished, so any chunking ends
    bit-identical), ``train`` -> (agent params, metrics), ``gradient_update`` (DQN
    only), ``validation_metrics`` and ``agent_params``.
    """

    config: Any
    task: Any
    env: Any
    env_params: Any
    network: Any
    init: Callable[..., Any]
    act: Callable[[Any, jax.Array], tuple[jax.Array, Any]]
    run: Callable[[Any, int], Any]
    train: Callable[..., tuple[Any, dict[str, jax.Array]]]
    gradient_update: Callable[..., tuple[tuple, jax.Array]] | None
    validation_metrics: Callable[[Any], dict[str, jax.Array]]
    agent_params: Callable[[Any], Any]


def make_trainer(
    config: Any,
    task: Any,
    network: Any,
    init: Callable[..., Any],
    act: Callable[[Any, jax.Array], tuple[jax.Array, Any]],
    run: Callable[[Any, int], Any],
    gradient_update: Callable[..., tuple[tuple, jax.Array]] | None = None,
) -> Trainer:
    """A learner's :class:`Trainer` from its ``act``, ``run`` and ``init(key, hp,
    env_params)``, whose last two default to the config's and the task's."""

    def init_state(key: jax.Array, hparams: Any = None, env_params: Any = None) -> Any:
        hp = config.hyperparams if hparams is None else hparams
        return init(key, hp, task.env_params if env_params is None else env_params)

    validation_metrics = functools.partial(candidate_metrics, config, task, network)
    agent_params = functools.partial(run_agent, config)

    def train(key: jax.Array, hparams: Any = None, env_params: Any = None):
        """Init, chunks in a ``lax.while_loop`` until finished, then the agent's choice:
        ``(agent params, metrics)``; ``vmap`` it over seeds."""
        state = init_state(key, hparams, env_params)
        state = jax.lax.while_loop(
            lambda s: ~s.finished, lambda s: run(s, config.chunk_iterations), state
        )
        if config.snapshots:
            state = state.replace(validation=validation_metrics(state))
        return agent_params(state), state.metrics

    return Trainer(
        config=config,
        task=task,
        env=task.env,
        env_params=task.env_params,
        network=network,
        init=init_state,
        act=act,
        run=run,
        train=train,
        gradient_update=gradient_update,
        validation_metrics=validation_metrics,
        agent_params=agent_params,
    )
