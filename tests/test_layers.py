"""The numerics under the networks' layers: convolution patches by slices and by one
gather against ``conv_general_dilated``, the LSTM cell against its equations."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.layers import gathered_patches, lstm_cell, patches
from tests.helpers import fast_jit, flat_random


@pytest.mark.parametrize(
    "shape, kh, kw, stride",
    [((3, 45, 30, 4), 8, 6, 4), ((2, 10, 7, 32), 4, 3, 3), ((2, 9, 11, 2), 3, 5, 2)],
)
def test_gathered_patches_are_the_sliced_patches(shape, kh, kw, stride):
    # the first layer's gather must copy exactly what the slices copy, in their order
    x = flat_random(jax.random.normal, jax.random.key(1), shape)
    gathered = np.asarray(fast_jit(gathered_patches, static_argnums=(1, 2, 3))(x, kh, kw, stride))
    sliced = np.asarray(fast_jit(patches, static_argnums=(1, 2, 3))(x, kh, kw, stride))
    assert gathered.shape == sliced.shape
    np.testing.assert_array_equal(gathered, sliced)
    # and the slices are the convolution's patches: one kernel per patch position
    w = flat_random(jax.random.normal, jax.random.key(2), (kh, kw, shape[-1], 1))
    conv = jax.lax.conv_general_dilated(
        x, w, (stride, stride), "VALID", dimension_numbers=("NHWC", "HWIO", "NHWC")
    )
    np.testing.assert_allclose(gathered @ w.reshape(-1, 1), np.asarray(conv), rtol=1e-4, atol=1e-4)


def test_lstm_cell_matches_numpy():
    rng = np.random.default_rng(0)
    n_in, hidden, batch = 5, 3, 2
    w = rng.normal(size=(n_in + hidden, 4 * hidden)).astype(np.float32)
    b = rng.normal(size=(4 * hidden,)).astype(np.float32)
    x = rng.normal(size=(batch, n_in)).astype(np.float32)
    h = rng.normal(size=(batch, hidden)).astype(np.float32)
    c = rng.normal(size=(batch, hidden)).astype(np.float32)

    def sigmoid(z):
        return 1.0 / (1.0 + np.exp(-z))

    z = np.concatenate([x, h], 1).astype(np.float64) @ w + b
    i, f, g, o = np.split(z, 4, axis=1)
    c_ref = sigmoid(f) * c + sigmoid(i) * np.tanh(g)
    h_ref = sigmoid(o) * np.tanh(c_ref)
    out, (h_new, c_new) = lstm_cell({"w": jnp.asarray(w), "b": jnp.asarray(b)}, x, (h, c))
    np.testing.assert_allclose(np.asarray(c_new), c_ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(h_new), h_ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(out), np.asarray(h_new))
