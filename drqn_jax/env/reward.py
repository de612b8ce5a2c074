"""The reward (paper §IV-B "Reward Function"; SPEC §5): collision ``r_c``, else
``TTC − 3`` for ``TTC ≤ 3 s``, else the speed reward ``r_v``; in [−10, 1] by default.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from drqn_jax.env.params import EnvParams

__all__ = ["reward", "speed_reward"]


def speed_reward(v: jax.Array, params: EnvParams) -> jax.Array:
    """r_v (paper eq. for r_v): () float32 for speed ``v`` (m/s)."""
    normal = 1.0 - (params.v_ref - v) * (1.0 / params.v_ref)
    r = jnp.where(v > params.v_ref, params.reward_overspeed, normal)
    return jnp.where(v < params.stopped_speed, params.reward_stopped, r).astype(jnp.float32)


def reward(collided: jax.Array, ttc: jax.Array, v: jax.Array, params: EnvParams) -> jax.Array:
    """() float32 reward of one step, from the post-step collision flag, TTC (s) and speed."""
    near = ttc <= params.ttc_threshold
    # ttc is inf when there is no near collision: keep inf out of the arithmetic.
    r_nc = jnp.where(near, ttc, params.ttc_threshold) - params.ttc_threshold
    r = jnp.where(near, r_nc, speed_reward(v, params))
    return jnp.where(collided, params.reward_collision, r).astype(jnp.float32)
