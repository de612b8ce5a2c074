"""The protocol every learner serves: a :class:`Trainer` of pure functions.

:func:`drqn_jax.learners.make_train` builds one for a
:class:`~drqn_jax.learners.hyperparams.TrainConfig`: the paper's Double-DQN on an
episode replay (``algorithm = "dqn"``, :mod:`drqn_jax.learners.dqn.train`), recurrent
PPO (``"ppo"``, :mod:`drqn_jax.learners.ppo`) or recurrent PQN (``"pqn"``,
:mod:`drqn_jax.learners.pqn`). The host loop (:mod:`drqn_jax.experiments.runner`),
sweeps, checkpoints, evaluation and the study use nothing else, so they treat
every learner alike. Each learner's state is its own class; every one has
``key``, ``hparams``, ``env_params``, ``online`` (the parameters trained),
``opt_state``, ``recorded`` / ``finished`` (the episode budget), ``env_steps``,
``grad_steps``, ``ep_loss_sum``, ``metrics`` (per training episode,
:mod:`drqn_jax.learners.common`) and ``validation`` (the candidates' validation
metrics; None for a learner that keeps no snapshots).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax

from drqn_jax.learners.selection import candidate_metrics, run_agent

__all__ = ["Trainer", "make_trainer"]


class Trainer(NamedTuple):
    """The pure functions of one training configuration.

    * ``init(key, hparams=None, env_params=None) -> state``;
    * ``act(state, key) -> (actions (N,), carry)``: the learner's behaviour;
    * ``run(state, num_iterations) -> state``: ``lax.scan`` over iterations
      (env steps of the DQN, updates of PPO and PQN); those after the run finished
      change nothing, so any chunking ends bit-identical;
    * ``train(key, hparams=None, env_params=None) -> (agent params, metrics)``;
    * ``gradient_update``: the DQN's single gradient step (benchmarks); None for PPO, PQN;
    * ``validation_metrics(state)``: the candidates' (``snapshots`` > 0);
    * ``agent_params(state)``: the run's agent, for ``network`` (greedy argmax).
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
    """A learner's :class:`Trainer` from its ``init``, ``act`` and ``run``: the
    whole run, validation and agent choice are the same for every learner
    (``network`` is the one the greedy agent plays)."""

    def validation_metrics(state: Any) -> dict[str, jax.Array]:
        return candidate_metrics(config, task, network, state)

    def agent_params(state: Any) -> Any:
        return run_agent(config, state)

    def train(key: jax.Array, hparams: Any = None, env_params: Any = None):
        """Init, then chunks of ``config.chunk_iterations`` in a ``lax.while_loop``
        until the run finished, then the choice of the run's agent:
        ``(agent params, metrics)``. ``jax.jit(jax.vmap(train))`` runs several
        seeds at once."""
        state = init(key, hparams, env_params)
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
        init=init,
        act=act,
        run=run,
        train=train,
        gradient_update=gradient_update,
        validation_metrics=validation_metrics,
        agent_params=agent_params,
    )
