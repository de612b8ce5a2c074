"""Double DQN loss over sequences (paper §II-E, §V-B; SPEC §7).

Online and target networks unroll once over a window's W + 1 observations
from a zero state. For transition t the target is

    y_t = r_t + γ (1 − terminated_t) Q_target(s_{t+1}, argmax_a Q_online(s_{t+1}, a))

— it bootstraps through truncation, never through termination. With
``n_step`` = n > 1 (not in the paper; R2D2-style, Kapturowski et al. 2019)
the target sums up to n rewards of the window before bootstrapping,

    y_t = Σ_{k<m} γ^k r_{t+k} + γ^m (1 − terminated) Q_target(s_{t+m}, a*_{t+m}),
    a*_j = argmax_a Q_online(s_j, a),

where m ≤ n stops at the episode's end (its last real transition) and at
the window's end; n = 1 is the one-step target above. The TD error
is clipped as the paper says ("limiting the error term to [−1, 1]"): Huber
loss with δ = 1 (``clip = "huber"``), or the authors' code, MSE with the
gradient clamped element-wise (``clip = "grad"``, see
:func:`drqn_jax.learners.optim.clip`). Padding is masked out of the mean.

Optionally (not in the paper; R2D2, Kapturowski et al. 2019, after Pohlen et
al. 2018) the values are rescaled: the network learns h(Q) with
h(x) = sign(x)(√(|x| + 1) − 1) + εx, so the target of any n becomes

    y_t = h(Σ_{k<m} γ^k r_{t+k} + γ^m (1 − terminated) h⁻¹(Q_target(s_{t+m}, a*_{t+m}))),

which shrinks large returns (a collision penalty of −100) without clipping
them away (``value_rescale = 1``; 0 is the paper's target bit for bit).

Optionally (not in the paper) a large-margin imitation term is added, as in
DQfD (Hester et al. 2018): for each step with an expert action a_E and a
weight w_t > 0,

    J_E(t) = max_a [Q(s_t, a) + l · 1(a ≠ a_E)] − Q(s_t, a_E),

which is zero once a_E's value leads every other action's by the margin l;
the loss is then Σ_t (TD_t + w_t J_E(t)) over the masked steps' count.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.learners.dqn.replay import Windows
from drqn_jax.learners.hyperparams import CLIP_MODES
from drqn_jax.networks import Network

#: ``Hyperparams.clip`` of the Huber loss and of the squared error (gradient clipping).
CLIP_HUBER, CLIP_GRAD = CLIP_MODES.index("huber"), CLIP_MODES.index("grad")
#: ε of the value rescaling h (R2D2's 10⁻³).
RESCALE_EPS = 1e-3

__all__ = [
    "double_dqn_targets",
    "huber",
    "large_margin",
    "n_step_targets",
    "rescale",
    "sequence_loss",
    "unrescale",
]


def huber(x: jax.Array, delta: float = 1.0) -> jax.Array:
    """Huber loss: ½x² for |x| ≤ δ, δ(|x| − ½δ) beyond (gradient clipped to ±δ)."""
    a = jnp.abs(x)
    return jnp.where(a <= delta, 0.5 * x * x, delta * (a - 0.5 * delta))


def rescale(x: jax.Array, eps: float = RESCALE_EPS) -> jax.Array:
    """R2D2's h(x) = sign(x)(√(|x| + 1) − 1) + εx (odd, increasing, h(0) = 0).

    √(|x| + 1) − 1 is computed as |x| / (√(|x| + 1) + 1): the same number without
    the cancellation that costs float32 its digits near 0.
    """
    a = jnp.abs(x)
    return jnp.sign(x) * a / (jnp.sqrt(a + 1.0) + 1.0) + eps * x


def unrescale(x: jax.Array, eps: float = RESCALE_EPS) -> jax.Array:
    """h⁻¹(x) = sign(x)(((√(1 + 4ε(|x| + 1 + ε)) − 1) / 2ε)² − 1), the inverse of
    :func:`rescale`, with (√(1 + z) − 1) / 2ε written as 2(|x| + 1 + ε) / (√(1 + z) + 1)."""
    b = jnp.abs(x) + 1.0 + eps
    root = 2.0 * b / (jnp.sqrt(1.0 + 4.0 * eps * b) + 1.0)
    return jnp.sign(x) * (root * root - 1.0)


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


def n_step_targets(
    q_online_next: jax.Array,
    q_target_next: jax.Array,
    reward: jax.Array,
    terminated: jax.Array,
    mask: jax.Array,
    gamma: float | jax.Array,
    n_step: int,
    value_rescale: int | jax.Array = 0,
) -> jax.Array:
    """n-step Double DQN targets (W, B) of a window (see the module docstring).

    Args:
        q_online_next, q_target_next: (W, B, A) Q-values at observations 1 … W.
        reward, terminated, mask: (W, B); ``mask`` is false on padding.
        n_step: static n ≥ 1 (n = 1: :func:`double_dqn_targets`).
        value_rescale: 1: the networks' values are h(Q) (:func:`rescale`): the
            bootstrap is unrescaled and the target rescaled; 0: the paper's.
    Returns:
        (W, B) float32 targets; those of padded steps are finite and meaningless.
    """
    on = jnp.asarray(value_rescale) == 1
    # Selected, not branched: with value_rescale = 0 the target is the paper's bit for bit.
    q_target_next = jnp.where(on, unrescale(q_target_next), q_target_next)
    if n_step == 1:
        y = double_dqn_targets(q_online_next, q_target_next, reward, terminated, gamma)
        return jnp.where(on, rescale(y), y)
    steps = reward.shape[0]
    best = jnp.argmax(q_online_next, axis=-1)
    value = jnp.take_along_axis(q_target_next, best[..., None], axis=-1)[..., 0]  # (W, B)

    def ahead(x: jax.Array, k: int, fill) -> jax.Array:  # x[t + k], ``fill`` past the end
        return jnp.concatenate([x[k:], jnp.full((k, *x.shape[1:]), fill, x.dtype)])

    gamma = jnp.asarray(gamma, jnp.float32)
    ret = jnp.zeros_like(reward)
    discount = jnp.ones_like(reward)  # γ^m of the steps taken so far
    alive = jnp.ones(reward.shape, bool)  # step t + k is still in the episode
    done = jnp.zeros(reward.shape, bool)  # the steps taken ended in termination
    last = jnp.zeros(reward.shape, jnp.int32)  # index of the next observation - 1
    for k in range(n_step):
        take = alive & ahead(mask, k, False)
        term_k = ahead(terminated, k, False)
        ret = jnp.where(take, ret + discount * ahead(reward, k, 0.0), ret)
        discount = jnp.where(take, discount * gamma, discount)
        done = done | (take & term_k)
        last = jnp.where(take, jnp.arange(steps)[:, None] + k, last)
        alive = take & ~term_k
    boot = jnp.take_along_axis(value, last, axis=0)
    y = ret + discount * (1.0 - done.astype(jnp.float32)) * boot
    return jnp.where(on, rescale(y), y)


def large_margin(q: jax.Array, expert_action: jax.Array, margin: float | jax.Array) -> jax.Array:
    """DQfD's supervised loss (…,) from Q-values (…, A) and expert actions (…,):
    ``max_a [Q(a) + margin · 1(a ≠ a_E)] − Q(a_E)`` ≥ 0."""
    num_actions = q.shape[-1]
    other = jnp.arange(num_actions) != expert_action[..., None]
    q_expert = jnp.take_along_axis(q, expert_action[..., None], axis=-1)[..., 0]
    return jnp.max(q + margin * other.astype(q.dtype), axis=-1) - q_expert


def _unroll(network: Network, params: Any, windows: Windows, carry: Any, burn_in: int) -> jax.Array:
    """Q-values (L + W + 1, B, A) of a window batch; with burn-in L the carry after
    the first L observations is cut from the gradient, as R2D2 does."""
    if not burn_in:
        return network.unroll(params, windows.obs, carry, windows.resets)[0]
    first, rest = (
        jax.tree.map(lambda x: x[:burn_in], windows.obs),
        jax.tree.map(lambda x: x[burn_in:], windows.obs),
    )
    q_burn, carry = network.unroll(params, first, carry, windows.resets[:burn_in])
    carry = jax.lax.stop_gradient(carry)
    q_rest, _ = network.unroll(params, rest, carry, windows.resets[burn_in:])
    return jnp.concatenate([jax.lax.stop_gradient(q_burn), q_rest])


def sequence_loss(
    online: Any,
    target: Any,
    windows: Windows,
    network: Network,
    gamma: float | jax.Array,
    clip_mode: int | jax.Array = CLIP_HUBER,
    n_step: int = 1,
    expert_action: jax.Array | None = None,
    expert_weight: jax.Array | None = None,
    margin: float | jax.Array = 1.0,
    value_rescale: int | jax.Array = 0,
    burn_in: int = 0,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Mean masked TD loss of a window batch (plus the imitation term), and diagnostics.

    Args:
        online, target: network parameters (gradients flow to ``online`` only).
        windows: time-major batch (W + 1 observations, W transitions, B windows).
        clip_mode: ``CLIP_HUBER`` (0) or ``CLIP_GRAD`` (1, MSE ½δ²).
        n_step: static number of rewards per target (1 = the paper).
        expert_action, expert_weight: (W, B) int32 and float32, the expert's
            action in each state and the weight of its :func:`large_margin` term
            (0: none); both None (the paper): no imitation term.
        margin: the margin l of :func:`large_margin`.
        value_rescale: 1: R2D2's value rescaling (:func:`n_step_targets`); 0: the paper.
        burn_in: static L: the windows' first L steps only warm the LSTM (R2D2's
            burn-in; they are masked out of the loss and no gradient flows back
            into them); 0: the paper, the LSTM starts from zeros — or from
            ``windows.carry``, the state stored while acting, when the replay
            keeps one (R2D2's stored state).
    Returns:
        () float32 loss, and ``{"td_abs": mean |δ|, "q_mean": mean Q(s, a),
        "margin": mean weighted J_E}`` (``margin`` with an expert only).
    """
    batch = windows.action.shape[1]
    carry = network.initial_carry((batch,))
    if windows.carry is not None:  # R2D2's stored state: data, not a path for gradients
        carry = jax.lax.stop_gradient(windows.carry)
    q_online = _unroll(network, online, windows, carry, burn_in)  # (W + 1, B, A)
    q_target = _unroll(network, target, windows, carry, burn_in)
    q_taken = jnp.take_along_axis(q_online[:-1], windows.action[..., None], axis=-1)[..., 0]
    y = n_step_targets(
        q_online[1:],
        q_target[1:],
        windows.reward,
        windows.terminated,
        windows.mask,
        gamma,
        n_step,
        value_rescale,
    )
    td = q_taken - jax.lax.stop_gradient(y)
    per_step = jnp.where(clip_mode == CLIP_GRAD, 0.5 * td * td, huber(td))
    weight = windows.mask.astype(jnp.float32)
    count = jnp.maximum(jnp.sum(weight), 1.0)
    loss = jnp.sum(per_step * weight) / count
    aux = {
        "td_abs": jnp.sum(jnp.abs(td) * weight) / count,
        "q_mean": jnp.sum(q_taken * weight) / count,
    }
    if expert_action is not None:
        supervised = large_margin(q_online[:-1], expert_action, margin)
        aux["margin"] = jnp.sum(supervised * expert_weight * weight) / count
        loss = loss + aux["margin"]
    return loss, aux
