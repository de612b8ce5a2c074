"""The urban-pedestrian simulator (SPEC §1–5): one pure module per concern.

* :mod:`~drqn_jax.env.road_map` — map and semantics (§1)
* :mod:`~drqn_jax.env.ego` — action → setpoint → PID → plant (§2)
* :mod:`~drqn_jax.env.pedestrians` — spawn, paths, walking, despawn (§3)
* :mod:`~drqn_jax.env.grid` — the 45 × 30 × 4 observation grid (§4)
* :mod:`~drqn_jax.env.collision` — collision, time to collision and the reward (§5)
* :mod:`~drqn_jax.env.urban` — the env that wires them (gymnax contract)
* :mod:`~drqn_jax.env.viewer` — how it is drawn: palette, raster, HUD (§1–5)
"""
