"""The numerics under Table I's layers (paper §V-A; SPEC §7): products, initialisers,
convolutions as patch products, LSTM/GRU cells and frame stacks, written so that the
same key gives the same bits alone, batched by ``vmap`` and on any number of devices."""

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

Params = dict[str, Any]
LSTMState = tuple[jax.Array, jax.Array]  # (h, c)


def _rows_product(x: jax.Array, g: jax.Array) -> jax.Array:
    """``xᵀ g`` summed over every leading axis: (..., m), (..., n) -> (m, n). ``xᵀ`` is
    materialised behind an ``optimization_barrier``: XLA:CPU would give ``x.T @ g`` to
    Eigen, whose sums split by thread-pool size."""
    rows = _rows(x)
    return jax.lax.optimization_barrier(rows.T) @ _rows(g)


def _rows(x: jax.Array) -> jax.Array:
    """(..., m) -> (k, m); ``-1`` cannot be inferred when m is 0 (PPO's empty extras)."""
    return x.reshape(math.prod(x.shape[:-1]), x.shape[-1])


@jax.custom_vjp
def affine(x: jax.Array, w: jax.Array, b: jax.Array) -> jax.Array:
    """``x @ w + b``: (..., n_in) @ (n_in, n_out) + (n_out,); both gradients from one
    product ``[x, 1]ᵀ g`` (a plain reduction for ``b`` is reordered under ``vmap``)."""
    return x @ w + b


def _affine_bwd(res: tuple, g: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    x, w = res
    rows = _rows(x)  # the ones join the 2-D rows (fewer temporaries than before the reshape)
    rows = jnp.concatenate([rows, jnp.ones((rows.shape[0], 1), rows.dtype)], axis=1)
    grad_wb = _rows_product(rows, g)  # (n_in + 1, n_out)
    return g @ w.T, grad_wb[:-1], grad_wb[-1]


affine.defvjp(lambda x, w, b: (x @ w + b, (x, w)), _affine_bwd)  # forward: value, residuals


@jax.custom_vjp
def matmul(x: jax.Array, w: jax.Array) -> jax.Array:
    """``x @ w``: (..., n_in) @ (n_in, n_out), its weight gradient by :func:`_rows_product`
    (autodiff's ``xᵀ g`` would depend on XLA:CPU's thread pool)."""
    return x @ w


def _matmul_bwd(res: tuple, g: jax.Array) -> tuple[jax.Array, jax.Array]:
    x, w = res
    return g @ w.T, _rows_product(x, g)


matmul.defvjp(lambda x, w: (x @ w, (x, w)), _matmul_bwd)


def glorot(key: jax.Array, shape: tuple[int, ...], fan_in: int, fan_out: int) -> jax.Array:
    """Glorot-uniform weights of ``shape``, drawn flat (same bits, compiles faster)."""
    limit = math.sqrt(6.0 / (fan_in + fan_out))
    flat = jax.random.uniform(key, (math.prod(shape),), jnp.float32, -limit, limit)
    return flat.reshape(shape)


def dense_init(key: jax.Array, n_in: int, n_out: int, norm: bool = False) -> Params:
    """Glorot weights (n_in, n_out) and zero bias (n_out,); with ``norm``, a
    LayerNorm's scale (ones) and bias (zeros) under ``"norm"``."""
    layer = {"w": glorot(key, (n_in, n_out), n_in, n_out), "b": jnp.zeros((n_out,), jnp.float32)}
    if norm:
        layer["norm"] = {"scale": jnp.ones((n_out,), jnp.float32), "bias": jnp.zeros((n_out,))}
    return layer


def dense_relu(layer: Params, x: jax.Array) -> jax.Array:
    """ReLU of a dense layer (..., n_in) -> (..., n_out), through a LayerNorm
    (Ba et al. 2016; ε 1e-6, as flax's) first when the layer has one."""
    y = affine(x, layer["w"], layer["b"])
    if "norm" in layer:
        mean = jnp.mean(y, axis=-1, keepdims=True)
        var = jnp.mean(jnp.square(y - mean), axis=-1, keepdims=True)
        y = (y - mean) * jax.lax.rsqrt(var + 1e-6) * layer["norm"]["scale"] + layer["norm"]["bias"]
    return jax.nn.relu(y)


def patches(x: jax.Array, kh: int, kw: int, stride: int) -> jax.Array:
    """(N, H, W, C) -> (N, H', W', kh·kw·C) VALID patches by strided slices; times
    :func:`kernel_matrix`, a convolution that ``vmap`` does not reorder."""
    _, h, w, _ = x.shape
    h_out, w_out = (h - kh) // stride + 1, (w - kw) // stride + 1
    rows = [
        x[:, i : i + stride * (h_out - 1) + 1 : stride, j : j + stride * (w_out - 1) + 1 : stride]
        for i in range(kh)
        for j in range(kw)
    ]
    return jnp.concatenate(rows, axis=-1)


def gathered_patches(x: jax.Array, kh: int, kw: int, stride: int) -> jax.Array:
    """:func:`patches` as one gather: faster, but its gradient sums in another order
    (acting only)."""
    n, h, w, c = x.shape
    h_out, w_out = (h - kh) // stride + 1, (w - kw) // stride + 1
    rows = np.arange(h_out)[:, None, None, None] * stride + np.arange(kh)[None, None, :, None]
    cols = np.arange(w_out)[None, :, None, None] * stride + np.arange(kw)[None, None, None, :]
    index = ((rows * w + cols)[..., None] * c + np.arange(c)).reshape(-1)  # (H'·W'·kh·kw·C,)
    return x.reshape(n, h * w * c)[:, index].reshape(n, h_out, w_out, kh * kw * c)


def kernel_matrix(w: jax.Array) -> jax.Array:
    """(kh, kw, C, F) kernel as the (kh·kw·C, F) matrix matching :func:`patches`."""
    return w.reshape(-1, w.shape[-1])


def lstm_init(key: jax.Array, n_in: int, n_hidden: int) -> Params:
    """Weights (n_in + H, 4H) of [x, h] -> gates (i, f, g, o), biases (4H,), forget's 1."""
    w = glorot(key, (n_in + n_hidden, 4 * n_hidden), n_in + n_hidden, n_hidden)
    b = jnp.zeros((4, n_hidden), jnp.float32).at[1].set(1.0).reshape(-1)
    return {"w": w, "b": b}


def lstm_cell(p: Params, x: jax.Array, state: LSTMState) -> tuple[jax.Array, LSTMState]:
    """One LSTM step ``c' = σ(f)c + σ(i)tanh(g)``, ``h' = σ(o)tanh(c')``: x (..., n_in),
    state ((..., H), (..., H)) -> h' (..., H), (h', c')."""
    h, c = state
    return _lstm_gates(affine(jnp.concatenate([x, h], axis=-1), p["w"], p["b"]), c)


def _lstm_gates(gates: jax.Array, c: jax.Array) -> tuple[jax.Array, LSTMState]:
    """h' and (h', c') from the pre-activations (..., 4H) of the gates (i, f, g, o)."""
    i, f, g, o = jnp.split(gates, 4, axis=-1)
    c = jax.nn.sigmoid(f) * c + jax.nn.sigmoid(i) * jnp.tanh(g)
    h = jax.nn.sigmoid(o) * jnp.tanh(c)
    return h, (h, c)


def gru_init(key: jax.Array, n_in: int, n_hidden: int) -> Params:
    """Weights (n_in + H, 3H) of [x, h] -> 3 gates (r, z, n), their biases (3H,) and
    the bias (H,) of h's part of n (flax's ``GRUCell`` layout); biases 0."""
    w = glorot(key, (n_in + n_hidden, 3 * n_hidden), n_in + n_hidden, n_hidden)
    b, b_hn = jnp.zeros((3 * n_hidden,), jnp.float32), jnp.zeros((n_hidden,), jnp.float32)
    return {"w": w, "b": b, "b_hn": b_hn}


def _gru_gates(
    x_gates: jax.Array, h: jax.Array, w_h: jax.Array, b_hn: jax.Array
) -> tuple[jax.Array, tuple[jax.Array]]:
    """h' and (h',) from the input's pre-activations (..., 3H) and the state h (..., H):
    r, z = σ(x_r + W_r h), σ(x_z + W_z h); n = tanh(x_n + r ⊙ (W_n h + b_hn));
    h' = (1 − z) ⊙ n + z ⊙ h (Cho et al. 2014, as flax's ``GRUCell``)."""
    x_r, x_z, x_n = jnp.split(x_gates, 3, axis=-1)
    h_r, h_z, h_n = jnp.split(matmul(h, w_h), 3, axis=-1)
    r, z = jax.nn.sigmoid(x_r + h_r), jax.nn.sigmoid(x_z + h_z)
    n = jnp.tanh(x_n + r * (h_n + b_hn))
    h = (1.0 - z) * n + z * h
    return h, (h,)


def gru_cell(p: Params, x: jax.Array, state: tuple[jax.Array]) -> tuple[jax.Array, tuple]:
    """One GRU step: x (..., n_in), state ((..., H),) -> h' (..., H), (h',)."""
    n_in = x.shape[-1]
    return _gru_gates(affine(x, p["w"][:n_in], p["b"]), state[0], p["w"][n_in:], p["b_hn"])


def recurrent_layer(
    p: Params,
    x: jax.Array,
    extra: jax.Array | None,
    state: Any,
    resets: jax.Array,
    cell: str,
    scan_unroll: int,
) -> tuple[jax.Array, Any]:
    """``cell`` (``"lstm"``/``"gru"``) over a time-major sequence ``[x, extra]``
    (T, B..., ·), state zeroed where ``resets`` (T, B...): outputs (T, B..., H) and
    the last state. The input projection is one product before the ``lax.scan``."""
    n_x = x.shape[-1]
    w = p["w"]
    x_gates = affine(x, w[:n_x], p["b"])
    n_in = n_x
    if extra is not None:
        n_in += extra.shape[-1]
        x_gates = x_gates + matmul(extra, w[n_x:n_in])
    w_h = w[n_in:]

    def body(state, xs):
        gates, reset = xs
        state = jax.tree.map(lambda s: jnp.where(reset[..., None], 0.0, s), state)
        if cell == "gru":
            h, state = _gru_gates(gates, state[0], w_h, p["b_hn"])
        else:
            h, state = _lstm_gates(gates + matmul(state[0], w_h), state[1])
        return state, h

    unroll = min(x.shape[0], scan_unroll)
    state, h = jax.lax.scan(body, state, (x_gates, resets), unroll=unroll)
    return h, state


def stacked(seen: jax.Array) -> jax.Array:
    """(..., k, rows, cols, C) grids, oldest first -> (..., rows, cols, k·C)."""
    moved = jnp.moveaxis(seen, -4, -2)  # (..., rows, cols, k, C)
    return moved.reshape((*moved.shape[:-2], -1))


def stack_sequence(
    grid: jax.Array, carry: jax.Array, resets: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Stacks (T, B..., rows, cols, k·C) of a sequence (T, B..., rows, cols, C) after
    ``carry`` (B..., k − 1, …), and the next carry; grids before an episode's last
    reset are zeros."""
    k = carry.shape[-4] + 1
    steps = grid.shape[0]
    before = jnp.moveaxis(carry, -4, 0)  # (k - 1, B..., rows, cols, C)
    frames = jnp.concatenate([before, grid])  # (k - 1 + T, B..., …)
    index = jax.lax.broadcasted_iota(jnp.int32, resets.shape, 0)  # (T, B...): t
    last_reset = jax.lax.cummax(jnp.where(resets, index, -steps - k), axis=0)  # (T, B...)
    frames_of_step = []
    for j in range(k):  # frame t - (k - 1) + j of step t
        when = index - (k - 1) + j
        keep = (when >= last_reset)[..., None, None, None]
        frames_of_step.append(jnp.where(keep, frames[j : j + steps], 0.0))
    seen = jnp.stack(frames_of_step, axis=-4)  # (T, B..., k, rows, cols, C)
    return stacked(seen), seen[-1, ..., 1:, :, :, :]
