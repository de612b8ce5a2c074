"""The hand-written Adam and RAdam against the textbook update and against optax (test extra)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from drqn_jax.learners import Hyperparams, TrainConfig
from drqn_jax.learners.optim import (
    adam,
    apply_updates,
    clip,
    clip_by_global_norm,
    optimizer_of,
    radam,
)


def _problem(seed=0):
    rng = np.random.default_rng(seed)
    params = {"w": jnp.asarray(rng.normal(size=(5, 3)), jnp.float32), "b": jnp.zeros(3)}
    x = jnp.asarray(rng.normal(size=(16, 5)), jnp.float32)
    y = jnp.asarray(rng.normal(size=(16, 3)), jnp.float32)

    def loss(p):
        return jnp.mean((x @ p["w"] + p["b"] - y) ** 2)

    return params, jax.grad(loss)


def test_adam_matches_textbook_update():
    """The same 100 gradients through ours and through the formulas in float64."""
    rng = np.random.default_rng(0)
    grads = rng.normal(size=(100, 4, 3)) * np.logspace(-3, 1, 100)[:, None, None]
    lr, b1, b2, eps = 1e-2, 0.9, 0.999, 1e-8
    opt = adam(lr, b1, b2, eps)
    params = jnp.zeros((4, 3), jnp.float32)
    state = opt.init(params)
    ref, m, v = np.zeros((4, 3)), np.zeros((4, 3)), np.zeros((4, 3))
    for t in range(1, 101):
        g = grads[t - 1]
        updates, state = opt.update(jnp.asarray(g, jnp.float32), state, params)
        params = apply_updates(params, updates)
        m = b1 * m + (1 - b1) * g
        v = b2 * v + (1 - b2) * g * g
        ref = ref - lr * (m / (1 - b1**t)) / (np.sqrt(v / (1 - b2**t)) + eps)
        np.testing.assert_allclose(np.asarray(params), ref, rtol=1e-5, atol=1e-6)
    assert int(state.count) == 100


@pytest.mark.parametrize(
    ("lr", "ours", "theirs", "atol"),
    [
        (1e-3, adam, optax.adam, 1e-6),
        (3e-2, adam, optax.adam, 1e-6),
        (3e-2, radam, optax.radam, 5e-6),
    ],
)
def test_adam_and_radam_match_optax_over_100_steps(lr, ours, theirs, atol):
    """RAdam's first steps (ρₜ < 5) are momentum steps, its later ones rectified:
    100 steps cross from one to the other. Each RAdam step equals optax's to
    ~1e-9; its rectification r, steep near the threshold, lets the last bits
    of the two orders of operations add up to ~2e-6 over the 100 steps."""
    params, grad = _problem(1)
    ours, theirs = ours(lr), theirs(lr)
    p_ours, p_theirs = params, params
    s_ours, s_theirs = ours.init(params), theirs.init(params)

    @jax.jit  # as training runs it, and one program (op by op: a hundred small ones)
    def steps(p_ours, s_ours, p_theirs, s_theirs):
        u, s_ours = ours.update(grad(p_ours), s_ours, p_ours)
        u_theirs, s_theirs = theirs.update(grad(p_theirs), s_theirs, p_theirs)
        return apply_updates(p_ours, u), s_ours, optax.apply_updates(p_theirs, u_theirs), s_theirs

    for _ in range(100):
        p_ours, s_ours, p_theirs, s_theirs = steps(p_ours, s_ours, p_theirs, s_theirs)
    for a, b in zip(jax.tree.leaves(p_ours), jax.tree.leaves(p_theirs), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=atol, rtol=0)
    assert not np.allclose(np.asarray(p_ours["w"]), np.asarray(params["w"]))  # it moved


def test_clip_matches_optax():
    params, grad = _problem(2)
    g = jax.tree.map(lambda x: 50.0 * x, grad(params))  # large, so the clamp bites
    ours = clip(g, 1.0)
    theirs, _ = optax.clip(1.0).update(g, optax.EmptyState(), params)
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(theirs), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert float(jnp.max(jnp.abs(ours["w"]))) == 1.0


@pytest.mark.parametrize("scale", [1e-3, 50.0])
def test_clip_by_global_norm_matches_optax(scale):
    """Below the limit the gradients pass unchanged; above it they are scaled to it."""
    params, grad = _problem(3)
    g = jax.tree.map(lambda x: scale * x, grad(params))
    ours = clip_by_global_norm(g, 0.5)
    theirs, _ = optax.clip_by_global_norm(0.5).update(g, optax.EmptyState(), params)
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(theirs), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-9)
    norm = float(optax.tree.norm(ours))
    assert norm <= 0.5 + 1e-6 and (norm > 0.49) == (scale > 1)


def test_adam_jits_and_vmaps_over_learning_rate():
    params, grad = _problem(3)
    g = grad(params)

    def one(lr):
        opt = adam(lr)
        u, _ = opt.update(g, opt.init(params), params)
        return u

    lrs = jnp.array([1e-3, 1e-2])
    batched = jax.jit(jax.vmap(one))(lrs)
    for i, lr in enumerate([1e-3, 1e-2]):
        single = one(lr)
        np.testing.assert_allclose(
            np.asarray(batched["w"][i]), np.asarray(single["w"]), rtol=1e-6, atol=1e-9
        )


def test_the_config_names_adam_or_radam():
    params = {"w": jnp.ones(3)}
    grads = {"w": jnp.asarray([1.0, -2.0, 0.5])}
    hp = Hyperparams(learning_rate=0.1)
    adam_step, _ = optimizer_of(TrainConfig(), hp).update(grads, adam(0.1).init(params))
    first, _ = optimizer_of(TrainConfig(optimizer="radam"), hp).update(
        grads, radam(0.1).init(params)
    )
    # step 1 of RAdam is −lr · m̂ = −lr · g (no division by sqrt(v̂)); Adam's is −lr · sign(g)
    np.testing.assert_allclose(np.asarray(first["w"]), [-0.1, 0.2, -0.05], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(adam_step["w"]), [-0.1, 0.1, -0.1], rtol=1e-6)
