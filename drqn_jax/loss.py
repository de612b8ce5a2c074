"""Double DQN loss over sequences (paper §II-E, §V-B; SPEC §7).

Online and target networks unroll once over a window's W + 1 observations
from a zero state. For transition t the target is

    y_t = r_t + γ (1 − terminated_t) Q_target(s_{t+1}, argmax_a Q_online(s_{t+1}, a))

— it bootstraps through truncation, never through termination. The TD error
is clipped as the paper says ("limiting the error term to [−1, 1]"): Huber
loss with δ = 1 (``clip = "huber"``), or the authors' code, MSE with the
gradient clamped element-wise (``clip = "grad"``, see
:func:`drqn_jax.optim.clip`). Padding is masked out of the mean.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.networks import Network
from drqn_jax.replay import Windows

CLIP_MODES = ("huber", "grad")
CLIP_HUBER, CLIP_GRAD = 0, 1

__all__ = ["CLIP_MODES", "double_dqn_targets", "huber", "sequence_loss"]


def huber(x: jax.Array, delta: float = 1.0) -> jax.Array:
    """Huber loss: ½x² for |x| ≤ δ, δ(|x| − ½δ) beyond (gradient clipped to ±δ)."""
    a = jnp.abs(x)
    return jnp.where(a <= delta, 0.5 * x * x, delta * (a - 0.5 * delta))


def double_dqn_targets(
    q_online_next: jax.Array,
    q_target_next: jax.Array,
    reward: jax.Array,
    terminated: jax.Array,
    gamma: float | jax.Array,
) -> jax.Array:
    """Double DQN targets (…,) from next-state Q-values (…, A) of both networks."""
    best = jnp.argmax(q_online_next, axis=-1)
    q_next = jnp.take_along_axis(q_target_next, best[..., None], axis=-1)[..., 0]
    return reward + gamma * (1.0 - terminated.astype(jnp.float32)) * q_next


def sequence_loss(
    online: Any,
    target: Any,
    windows: Windows,
    network: Network,
    gamma: float | jax.Array,
    clip_mode: int | jax.Array = CLIP_HUBER,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Mean masked TD loss of a window batch, and diagnostics.

    Args:
        online, target: network parameters (gradients flow to ``online`` only).
        windows: time-major batch (W + 1 observations, W transitions, B windows).
        clip_mode: ``CLIP_HUBER`` (0) or ``CLIP_GRAD`` (1, MSE ½δ²).
    Returns:
        () float32 loss, and ``{"td_abs": mean |δ|, "q_mean": mean Q(s, a)}``.
    """
    steps, batch = windows.action.shape
    resets = jnp.zeros((steps + 1, batch), bool)
    carry = network.initial_carry((batch,))
    q_online, _ = network.unroll(online, windows.obs, carry, resets)  # (W + 1, B, A)
    q_target, _ = network.unroll(target, windows.obs, carry, resets)
    q_taken = jnp.take_along_axis(q_online[:-1], windows.action[..., None], axis=-1)[..., 0]
    y = double_dqn_targets(q_online[1:], q_target[1:], windows.reward, windows.terminated, gamma)
    td = q_taken - jax.lax.stop_gradient(y)
    per_step = jnp.where(clip_mode == CLIP_GRAD, 0.5 * td * td, huber(td))
    weight = windows.mask.astype(jnp.float32)
    count = jnp.maximum(jnp.sum(weight), 1.0)
    loss = jnp.sum(per_step * weight) / count
    aux = {
        "td_abs": jnp.sum(jnp.abs(td) * weight) / count,
        "q_mean": jnp.sum(q_taken * weight) / count,
    }
    return loss, aux
