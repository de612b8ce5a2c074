"""The learners (paper §V-B, Tables I–II; SPEC §7): what every learner shares, and
one subpackage or module per algorithm.

Shared (none of them imports a learner): :mod:`~drqn_jax.learners.optim` (Adam
by hand), :mod:`~drqn_jax.learners.task` (any gymnax-contract env as a learner
sees it), :mod:`~drqn_jax.learners.hyperparams` (``TrainConfig`` and the traced
``Hyperparams``), :mod:`~drqn_jax.learners.common` (per-episode bookkeeping, the
ε schedule, the on-policy rollout and minibatch epochs),
:mod:`~drqn_jax.learners.selection` (the run's agent among its snapshots) and
:mod:`~drqn_jax.learners.trainer` (the ``Trainer`` every learner returns).

Algorithms, each with its own state: :mod:`drqn_jax.learners.dqn` (the paper's
replay DRQN and its DQN ablations: acting, update, loss, replay),
:mod:`drqn_jax.learners.ppo` (recurrent PPO) and :mod:`drqn_jax.learners.pqn`
(recurrent PQN); none imports another.
:func:`make_train` picks one by ``TrainConfig.algorithm``.
The networks themselves (Table I) are :mod:`drqn_jax.networks`, one level up:
the agents run them too.
"""

from __future__ import annotations

from drqn_jax.learners.dqn.state import TrainState
from drqn_jax.learners.dqn.train import make_dqn
from drqn_jax.learners.hyperparams import Hyperparams, TrainConfig
from drqn_jax.learners.ppo import make_ppo
from drqn_jax.learners.pqn import make_pqn
from drqn_jax.learners.trainer import Trainer

__all__ = ["Hyperparams", "TrainConfig", "TrainState", "Trainer", "make_train"]


def make_train(config: TrainConfig | None = None) -> Trainer:
    """The pure training functions of ``config`` (default: ``TrainConfig()``): the
    replay DQN's (:func:`~drqn_jax.learners.dqn.train.make_dqn`) or recurrent PPO's
    (``algorithm = "ppo"``, :func:`~drqn_jax.learners.ppo.make_ppo`) or recurrent
    PQN's (``"pqn"``, :func:`~drqn_jax.learners.pqn.make_pqn`).

    Equal configurations get the same :class:`Trainer` (the same function
    objects), so ``jax.jit`` reuses what it compiled for them.
    """
    config = TrainConfig() if config is None else config
    if config.algorithm == "ppo":
        return make_ppo(config)
    if config.algorithm == "pqn":
        return make_pqn(config)
    return make_dqn(config)
