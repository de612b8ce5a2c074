"""Adam, RAdam (optax's ``init``/``update`` shape) and gradient clamps by hand (paper §V-B;
SPEC §7); hyperparameters may be traced arrays, so a sweep can ``vmap`` over them."""

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

Params = Any

#: The optimisers a learner may take (``TrainConfig.optimizer``).
OPTIMIZERS = ("adam", "radam")


class GradientTransformation(NamedTuple):
    """optax-shaped pair of pure functions."""

    init: Callable[[Params], Any]
    update: Callable[[Params, Any, Params | None], tuple[Params, Any]]


class AdamState(NamedTuple):
    """Step count and the first and second moment estimates (same tree as params)."""

    count: jax.Array
    mu: Params
    nu: Params


def adam(
    learning_rate: float | jax.Array,
    b1: float | jax.Array = 0.9,
    b2: float | jax.Array = 0.999,
    eps: float | jax.Array = 1e-8,
) -> GradientTransformation:
    """Adam (Kingma & Ba 2015) as ``optax.adam``: ``m ← b1·m + (1−b1)·g``; ``v ← b2·v +
    (1−b2)·g²``; ``update = −lr · (m / (1−b1ᵗ)) / (sqrt(v / (1−b2ᵗ)) + eps)``."""

    def update(grads: Params, state: AdamState, params: Params | None = None):
        count, mu, nu = _moments(grads, state, b1, b2)
        t = count.astype(jnp.float32)
        # Reciprocals multiplied, not scalars divided: XLA rewrites ``x / c`` for a
        # broadcast scalar ``c`` (one run) but not for a per-seed ``c`` (vmap), and
        # the two round differently.
        mu_scale = 1.0 / (1.0 - b1**t)
        nu_scale = 1.0 / (1.0 - b2**t)
        updates = jax.tree.map(
            lambda m, v: -learning_rate * (m * mu_scale) / (jnp.sqrt(v * nu_scale) + eps), mu, nu
        )
        return updates, AdamState(count=count, mu=mu, nu=nu)

    return GradientTransformation(_adam_init, update)


def _adam_init(params: Params) -> AdamState:
    zeros = jax.tree.map(jnp.zeros_like, params)
    return AdamState(count=jnp.zeros((), jnp.int32), mu=zeros, nu=zeros)


def _moments(grads: Params, state: AdamState, b1: Any, b2: Any) -> tuple[jax.Array, Any, Any]:
    """Adam's step count and moving first and second moments after ``grads``."""
    mu = jax.tree.map(lambda m, g: b1 * m + (1.0 - b1) * g, state.mu, grads)
    nu = jax.tree.map(lambda v, g: b2 * v + (1.0 - b2) * g * g, state.nu, grads)
    return state.count + 1, mu, nu


def radam(
    learning_rate: float | jax.Array,
    b1: float | jax.Array = 0.9,
    b2: float | jax.Array = 0.999,
    eps: float | jax.Array = 1e-8,
    threshold: float = 5.0,
) -> GradientTransformation:
    """Rectified Adam (Liu et al. 2020) as ``optax.radam`` (purejaxql's PQN): Adam's moments;
    with ρ∞ = 2 / (1 − b2) − 1, ρₜ = ρ∞ − 2t·b2ᵗ / (1 − b2ᵗ) and r = sqrt((ρₜ − 4)(ρₜ − 2)ρ∞ /
    ((ρ∞ − 4)(ρ∞ − 2)ρₜ)), the update is −lr · r·m̂ / (sqrt(v̂) + eps) once ρₜ ≥ ``threshold``,
    else −lr · m̂ (the variance of v̂ not yet tractable)."""
    ro_inf = 2.0 / (1.0 - b2) - 1.0

    def update(grads: Params, state: AdamState, params: Params | None = None):
        count, mu, nu = _moments(grads, state, b1, b2)
        # powers by the integer step count, as optax's: ρₜ cancels 1999 − 1994 near
        # the threshold, so a float power's rounding moves r by ~0.5 % there
        b2t = b2**count
        ro = ro_inf - 2 * count * b2t / (1 - b2t)
        rectified = ro >= threshold
        safe_ro = jnp.where(rectified, ro, threshold)  # no sqrt of a negative
        r = jnp.sqrt(
            (safe_ro - 4.0) * (safe_ro - 2.0) * ro_inf / ((ro_inf - 4.0) * (ro_inf - 2.0) * safe_ro)
        )
        mu_corr, nu_corr = 1 - b1**count, 1 - b2t

        def step(m, v):
            m_hat = m / mu_corr
            return -learning_rate * jnp.where(
                rectified, r * m_hat / (jnp.sqrt(v / nu_corr) + eps), m_hat
            )

        return jax.tree.map(step, mu, nu), AdamState(count=count, mu=mu, nu=nu)

    return GradientTransformation(_adam_init, update)


def clip(grads: Params, max_delta: float | jax.Array) -> Params:
    """Every gradient element clamped to ``[−max_delta, max_delta]`` (optax.clip)."""
    return jax.tree.map(lambda g: jnp.clip(g, -max_delta, max_delta), grads)


def clip_by_global_norm(grads: Params, max_norm: float | jax.Array) -> Params:
    """The gradients scaled so that their global L2 norm is at most ``max_norm``
    (optax.clip_by_global_norm; PPO's ``max_grad_norm``)."""
    norm = jnp.sqrt(sum(jnp.sum(g * g) for g in jax.tree.leaves(grads)))
    scale = jnp.where(norm < max_norm, 1.0, max_norm / norm)
    return jax.tree.map(lambda g: (g * scale).astype(g.dtype), grads)


def optimizer_of(
    config: Any, hp: Any, learning_rate: jax.Array | None = None
) -> GradientTransformation:
    """``TrainConfig.optimizer`` (adam or radam) at the ``Hyperparams`` ``hp``'s
    settings (``learning_rate``: its own by default)."""
    lr = hp.learning_rate if learning_rate is None else learning_rate
    make = {"adam": adam, "radam": radam}[config.optimizer]
    return make(lr, hp.adam_b1, hp.adam_b2, hp.adam_eps)


def apply_updates(params: Params, updates: Params) -> Params:
    """``params + updates``, leaf by leaf, keeping each leaf's dtype."""
    return jax.tree.map(lambda p, u: (p + u).astype(p.dtype), params, updates)
