"""The learners (paper §V-B; SPEC §7): shared modules and one per algorithm (``dqn``, ``ppo``,
``pqn``; none imports another); :func:`make_train` picks by ``TrainConfig.algorithm``."""

from drqn_jax.learners.common import Trainer
from drqn_jax.learners.dqn.train import TrainState, make_dqn
from drqn_jax.learners.hyperparams import Hyperparams, TrainConfig
from drqn_jax.learners.ppo import make_ppo
from drqn_jax.learners.pqn import make_pqn

__all__ = ["Hyperparams", "TrainConfig", "TrainState", "Trainer", "make_train"]


def make_train(config: TrainConfig | None = None) -> Trainer:
    """The :class:`Trainer` of ``config`` (default ``TrainConfig()``) by its algorithm;
    equal configs get the same functions, so ``jax.jit`` reuses their compilations."""
    config = TrainConfig() if config is None else config
    return {"dqn": make_dqn, "ppo": make_ppo, "pqn": make_pqn}[config.algorithm](config)
