"""Double DQN loss over sequences (paper §II-E, §V-B; SPEC §7).

    y_t = Σ_{k<m} γ^k r_{t+k} + γ^m (1 − terminated) Q_target(s_{t+m}, argmax_a Q_online)

with m ≤ ``n_step`` (1 = the paper), bootstrapping through truncation only; the TD error
clipped (paper: "[−1, 1]"): Huber δ = 1 or a clamped gradient. Not in the paper: R2D2's value
rescaling h and DQfD's large-margin imitation term J_E. Padding is masked out."""

from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.learners.dqn.replay import Windows
from drqn_jax.learners.hyperparams import CLIP_MODES, Hyperparams
from drqn_jax.networks import Network

#: ``Hyperparams.clip`` of the Huber loss and of the squared error (gradient clipping).
CLIP_HUBER, CLIP_GRAD = CLIP_MODES.index("huber"), CLIP_MODES.index("grad")
#: ε of the value rescaling h (R2D2's 10⁻³).
RESCALE_EPS = 1e-3


def huber(x: jax.Array, delta: float = 1.0) -> jax.Array:
    """Huber loss: ½x² for |x| ≤ δ, δ(|x| − ½δ) beyond (gradient clipped to ±δ)."""
    a = jnp.abs(x)
    return jnp.where(a <= delta, 0.5 * x * x, delta * (a - 0.5 * delta))


def rescale(x: jax.Array, eps: float = RESCALE_EPS) -> jax.Array:
    """R2D2's h(x) = sign(x)(√(|x| + 1) − 1) + εx, written without cancellation near 0."""
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
    """n-step Double DQN targets (W, B) from Q-values (W, B, A) at observations 1 … W
    and reward/terminated/mask (W, B); ``value_rescale`` 1 works in h(Q) space.
    Padded steps' targets are finite and meaningless."""
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
    first = jax.tree.map(lambda x: x[:burn_in], windows.obs)
    rest = jax.tree.map(lambda x: x[burn_in:], windows.obs)
    q_burn, carry = network.unroll(params, first, carry, windows.resets[:burn_in])
    carry = jax.lax.stop_gradient(carry)
    q_rest, _ = network.unroll(params, rest, carry, windows.resets[burn_in:])
    return jnp.concatenate([jax.lax.stop_gradient(q_burn), q_rest])


def sequence_loss(
    online: Any,
    target: Any,
    windows: Windows,
    network: Network,
    hp: Hyperparams,
    n_step: int = 1,
    expert_action: jax.Array | None = None,
    expert_weight: jax.Array | None = None,
    burn_in: int = 0,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Mean masked TD loss of a window batch (W + 1 obs, B) with ``hp``'s per-decision
    ``gamma``, plus the imitation term where ``expert_action``/``expert_weight`` (W, B) are
    given (None: the paper). Gradients reach ``online`` only; ``burn_in`` steps only warm the
    LSTM. Returns () loss and ``{"td_abs", "q_mean"[, "margin"]}``."""
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
        hp.gamma,
        n_step,
        hp.value_rescale,
    )
    td = q_taken - jax.lax.stop_gradient(y)
    per_step = jnp.where(hp.clip == CLIP_GRAD, 0.5 * td * td, huber(td))
    weight = windows.mask.astype(jnp.float32)
    count = jnp.maximum(jnp.sum(weight), 1.0)
    loss = jnp.sum(per_step * weight) / count
    aux = {
        "td_abs": jnp.sum(jnp.abs(td) * weight) / count,
        "q_mean": jnp.sum(q_taken * weight) / count,
    }
    if expert_action is not None:
        supervised = large_margin(q_online[:-1], expert_action, hp.imitation_margin)
        aux["margin"] = jnp.sum(supervised * expert_weight * weight) / count
        loss = loss + aux["margin"]
    return loss, aux
