"""The replay DQN's :class:`TrainState` (paper §V-B; SPEC §7)."""

from __future__ import annotations

from typing import Any

import jax

from drqn_jax.learners.common import LearnerState
from drqn_jax.learners.dqn.replay import EpisodeReplay
from drqn_jax.pytree import pytree_dataclass

__all__ = ["TrainState"]


@pytree_dataclass
class TrainState(LearnerState):
    """Everything a replay DQN run carries between iterations (and checkpoints)."""

    target: Any
    replay: EpisodeReplay
    epsilon: jax.Array  # (N,) float32 ε of each env's current episode
    snapshots: Any = None  # [K, ...] online parameters during training; None when K = 0
    validation: Any = None  # {VALIDATION_METRICS: (K + 1,) float32}, NaN until validated
