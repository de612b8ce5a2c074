"""The urban-pedestrian simulator (SPEC §1–5): one pure module per concern.

* :mod:`~drqn_jax.env.road_map` — map and semantics (§1)
* :mod:`~drqn_jax.env.ego` — action → setpoint → PID → plant (§2)
* :mod:`~drqn_jax.env.pedestrians` — spawn, paths, walking, despawn (§3)
* :mod:`~drqn_jax.env.grid` — the 45 × 30 × 4 observation grid (§4)
* :mod:`~drqn_jax.env.collision` — collision and time to collision (§5)
* :mod:`~drqn_jax.env.reward` — the reward (§5)
* :mod:`~drqn_jax.env.urban` — the env that wires them (gymnax contract)
* :mod:`~drqn_jax.env.viewer` — how it is drawn: palette, raster, HUD (§1–5)
"""

from drqn_jax.env.params import KMH, EnvParams, StaticEnvParams
from drqn_jax.env.state import (
    ACCELERATE,
    ACTIONS,
    BEHAVIOURS,
    BRAKE,
    CROSSING,
    JAYWALKING,
    NO_ACTION,
    NUM_ACTIONS,
    SIDEWALK,
    SLOW_DOWN,
    STEER,
    EgoState,
    EnvState,
    Observation,
    PedestrianState,
)
from drqn_jax.env.urban import UrbanPedestrians

__all__ = [
    "ACCELERATE",
    "ACTIONS",
    "BEHAVIOURS",
    "BRAKE",
    "CROSSING",
    "JAYWALKING",
    "KMH",
    "NO_ACTION",
    "NUM_ACTIONS",
    "SIDEWALK",
    "SLOW_DOWN",
    "STEER",
    "EgoState",
    "EnvParams",
    "EnvState",
    "Observation",
    "PedestrianState",
    "StaticEnvParams",
    "UrbanPedestrians",
]
