"""The replay DQN's :class:`TrainState` (paper §V-B; SPEC §7)."""

from __future__ import annotations

from typing import Any

import jax

from drqn_jax.learners.common import budget_met
from drqn_jax.learners.dqn.replay import EpisodeReplay
from drqn_jax.learners.hyperparams import Hyperparams
from drqn_jax.pytree import pytree_dataclass

__all__ = ["TrainState"]


@pytree_dataclass
class TrainState:
    """Everything a training run carries between iterations (and checkpoints); per-env
    leaves (N, …), ``metrics`` (num_episodes,) per name."""

    key: jax.Array
    hparams: Hyperparams
    env_params: Any
    env_state: Any
    obs: Any
    carry: Any
    online: Any
    target: Any
    opt_state: Any
    replay: EpisodeReplay
    episode: jax.Array  # (N,) int32 index of each env's current episode
    epsilon: jax.Array  # (N,) float32 ε of each env's current episode
    ep_return: jax.Array
    ep_length: jax.Array
    ep_loss_sum: jax.Array
    ep_loss_count: jax.Array
    episodes_started: jax.Array
    recorded: jax.Array  # () int32 training episodes whose metrics are written
    grad_steps: jax.Array
    env_steps: jax.Array
    step_budget: jax.Array  # () int32 TrainConfig.num_env_steps (0: none)
    metrics: dict[str, jax.Array]
    snapshots: Any = None  # [K, ...] online parameters during training; None when K = 0
    validation: Any = None  # {VALIDATION_METRICS: (K + 1,) float32}, NaN until validated

    @property
    def finished(self) -> jax.Array:
        return budget_met(self)
