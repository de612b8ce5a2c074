"""The DRQN of paper §V-A (Table I, Fig. 3) and a DQN ablation, as plain pytrees (SPEC §7).

Layers (default widths, Table I):

* conv 8×6 stride 4, 32 filters, ReLU → conv 4×3 stride 3, 64, ReLU → conv
  2×2 stride 2, 64, ReLU (VALID; 45×30 → 10×7 → 3×2 → 1×1) → flatten (64);
* ``drqn``: LSTM1 (256) on the conv features → LSTM2 (256) fed
  ``[h1, speed, one-hot last action]``; ``dqn``: two dense ReLU layers in
  their place (same inputs, no memory, empty carry); ``dqn`` with ``frames``
  = k > 1 sees the last k grids stacked along the channels (the classic
  frame-stacking DQN, Mnih et al. 2015), its carry the k − 1 grids before;
* FC 256 ReLU → linear, 4 Q-values.

The conv stack is the torso for the paper's grid observation. For an
environment whose observation is a flat vector (any env of the gymnax
contract, :mod:`drqn_jax.learners.task`) the torso is an MLP instead (``torso =
"mlp"``: dense ReLU layers of widths ``mlp``), and the core sees its features
alone (no speed, no last action); the core and head are the same.

The LSTM is the standard one (gates i, f, g, o; ``c' = σ(f)c + σ(i)tanh(g)``,
``h' = σ(o)tanh(c')``) with the forget-gate bias initialised to 1.

:func:`make_network` returns a :class:`Network` of pure functions:
``init(key) -> params``; ``initial_carry(batch_shape) -> carry`` (zeros);
``step(params, obs, carry) -> (q, carry)`` for one time step with any leading
batch shape (acting); ``unroll(params, obs_seq, carry, resets) -> (q_seq,
carry)`` over a time-major ``(T, B, …)`` sequence (learning), zeroing the carry
at the steps where ``resets`` is true (an episode starts there).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.env.state import NUM_ACTIONS, Observation
from drqn_jax.programs import cached_program

Params = dict[str, Any]
LSTMState = tuple[jax.Array, jax.Array]  # (h, c)
Carry = Any

NETWORK_KINDS = ("drqn", "dqn")
#: The recurrent cells of kind ``drqn``: the paper's LSTM (Table I) and a GRU.
CELLS = ("lstm", "gru")
#: What reads the observation: Table I's conv stack (grids) or an MLP (flat vectors).
TORSOS = ("conv", "mlp")

__all__ = [
    "CELLS",
    "NETWORK_KINDS",
    "TORSOS",
    "Network",
    "NetworkConfig",
    "affine",
    "conv_torso",
    "lstm_cell",
    "make_network",
    "param_count",
]


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Shape-setting settings of the Q-network (hashable: a static argument).

    Attributes:
        kind: ``"drqn"`` (LSTMs) or ``"dqn"`` (dense layers, the ablation).
        conv: ``(kernel_h, kernel_w, stride, filters)`` per conv layer (Table I).
        recurrent: width of LSTM1 and LSTM2 (or of the dense layers for ``dqn``).
        hidden: width of the FC layer before the Q-values.
        frames: for ``dqn``, how many of the last grids it sees stacked (1: the
            current one only).
        grid_shape: ``(rows, cols, channels)`` of the observation grid.
        num_actions: number of Q-values.
        torso: ``"conv"`` (the grid, speed and last action of the paper's env)
            or ``"mlp"`` (a flat observation vector of ``obs_size`` floats);
            chosen from the environment's observation by the trainer.
        mlp: widths of the MLP torso's dense ReLU layers.
        obs_size: length of the flat observation (``torso = "mlp"``).
        layer_norm: LayerNorm (learned scale and bias) before the ReLU of every
            dense layer of the MLP torso and of the FC layer (PQN's; False:
            Table I, none).
        cell: the recurrent cell of kind ``drqn``: ``"lstm"`` (Table I) or
            ``"gru"`` (purejaxql's recurrent PQN; :func:`gru_cell`).
        scan_unroll: steps of each recurrent layer's ``lax.scan`` (an unroll)
            written out per loop iteration: the same bits whatever its value; more
            compile longer (9: the paper's windows whole, PPO's rollouts in blocks).
    """

    kind: str = "drqn"
    conv: tuple[tuple[int, int, int, int], ...] = ((8, 6, 4, 32), (4, 3, 3, 64), (2, 2, 2, 64))
    recurrent: int = 256
    hidden: int = 256
    frames: int = 1
    grid_shape: tuple[int, int, int] = (45, 30, 4)
    num_actions: int = NUM_ACTIONS
    torso: str = "conv"
    mlp: tuple[int, ...] = (64,)
    obs_size: int = 0
    layer_norm: bool = False
    cell: str = "lstm"
    scan_unroll: int = 9

    def __post_init__(self) -> None:
        if not isinstance(self.layer_norm, bool):
            raise ValueError(
                f"NetworkConfig.layer_norm = {self.layer_norm!r}: must be true or false"
            )
        if self.kind not in NETWORK_KINDS:
            raise ValueError(f"NetworkConfig.kind = {self.kind!r}: must be one of {NETWORK_KINDS}")
        if self.cell not in CELLS:
            raise ValueError(f"NetworkConfig.cell = {self.cell!r}: must be one of {CELLS}")
        if self.cell != "lstm" and self.kind != "drqn":
            raise ValueError(
                f"NetworkConfig.cell = {self.cell!r}: a cell is for kind 'drqn' (kind "
                f"{self.kind!r} has none); use 'lstm'"
            )
        if self.torso not in TORSOS:
            raise ValueError(f"NetworkConfig.torso = {self.torso!r}: must be one of {TORSOS}")
        if self.torso == "mlp":
            if self.obs_size < 1 or any(not isinstance(w, int) or w < 1 for w in self.mlp):
                raise ValueError(
                    f"NetworkConfig.mlp = {self.mlp!r}, obs_size = {self.obs_size!r}: the MLP "
                    "torso needs integer widths >= 1 and a flat observation of >= 1 floats"
                )
            if self.frames > 1:
                raise ValueError(
                    f"NetworkConfig.frames = {self.frames}: stacking is for grids (torso "
                    "'conv'); use 1"
                )
        for name in ("recurrent", "hidden", "frames", "num_actions", "scan_unroll"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"NetworkConfig.{name} = {value!r}: must be an integer >= 1")
        if self.frames > 1 and self.kind != "dqn":
            raise ValueError(
                f"NetworkConfig.frames = {self.frames}: stacking grids is for kind 'dqn' "
                f"(kind {self.kind!r} remembers through its LSTMs); use 1"
            )
        if self.torso == "conv":
            self._check_conv()

    def _check_conv(self) -> None:
        h, w, _ = self.grid_shape
        for kh, kw, stride, filters in self.conv:
            if min(kh, kw, stride, filters) < 1:
                raise ValueError(f"NetworkConfig.conv = {self.conv!r}: all sizes must be >= 1")
            h, w = (h - kh) // stride + 1, (w - kw) // stride + 1
            if h < 1 or w < 1:
                raise ValueError(
                    f"NetworkConfig.conv = {self.conv!r}: the grid {self.grid_shape} shrinks to "
                    "nothing; the conv stack needs at least a 1×1 output"
                )

    @property
    def conv_output_shape(self) -> tuple[int, int, int]:
        """``(h, w, filters)`` after the conv stack: (1, 1, 64) for Table I."""
        h, w, c = self.grid_shape
        for kh, kw, stride, filters in self.conv:
            h, w, c = (h - kh) // stride + 1, (w - kw) // stride + 1, filters
        return h, w, c

    @property
    def features(self) -> int:
        """Width of the torso's output: the flattened conv output (64), or the
        MLP's last layer."""
        if self.torso == "mlp":
            return self.mlp[-1] if self.mlp else self.obs_size
        return math.prod(self.conv_output_shape)

    @property
    def extra_inputs(self) -> int:
        """Width of what LSTM2 (or dense2) sees beside LSTM1's output: speed and the
        one-hot last action (1 + A) with the conv torso, nothing with the MLP."""
        return 1 + self.num_actions if self.torso == "conv" else 0


class Network(NamedTuple):
    """Pure functions of one Q-network architecture (see the module docstring)."""

    config: NetworkConfig
    init: Callable[[jax.Array], Params]
    initial_carry: Callable[[tuple[int, ...]], Carry]
    step: Callable[[Params, Observation, Carry], tuple[jax.Array, Carry]]
    unroll: Callable[[Params, Observation, Carry, jax.Array], tuple[jax.Array, Carry]]


def _rows_product(x: jax.Array, g: jax.Array) -> jax.Array:
    """``xᵀ g`` summed over every leading axis: (..., m), (..., n) -> (m, n), a weight's
    gradient, with the same bits whatever XLA:CPU's thread pool.

    XLA:CPU hands a product that contracts its left operand's leading axis (as
    ``x.T @ g`` and autodiff's weight gradients do) to Eigen, which splits
    its sums by the size of the process's thread pool: max(cores, forced host
    devices), so 4 forced devices on 2 cores would round every gradient
    differently from one device. A row-major ``(m, k) @ (k, n)`` goes to
    YNNPACK, whose sums do not depend on the pool, batched (``vmap``) or not.
    So ``xᵀ`` is materialised first: ``optimization_barrier`` keeps XLA from
    folding the transpose back into the product (it costs one copy of ``x``).
    A vector-matrix product (the acting network on one environment) still goes
    to Eigen, but Eigen does not split those by the pool.
    """
    rows = _rows(x)
    return jax.lax.optimization_barrier(rows.T) @ _rows(g)


def _rows(x: jax.Array) -> jax.Array:
    """(..., m) -> (k, m), k the product of the leading axes (``-1`` cannot be
    inferred when m is 0, as PPO's empty extra inputs)."""
    return x.reshape(math.prod(x.shape[:-1]), x.shape[-1])


@jax.custom_vjp
def affine(x: jax.Array, w: jax.Array, b: jax.Array) -> jax.Array:
    """``x @ w + b``: (..., n_in) @ (n_in, n_out) + (n_out,), with a vmap-stable gradient.

    The gradients of ``w`` and ``b`` are sums over every leading axis. A plain
    reduction for ``b`` is ordered differently by XLA:CPU once ``vmap`` adds a
    seed axis (a batched run would drift by an ulp from the same run alone),
    so both come out of ONE matrix product, ``[x, 1]ᵀ g`` (:func:`_rows_product`,
    which does not depend on the thread pool either), which XLA batches
    exactly. (A separate ones-vector product for ``b`` does the same, but
    XLA:CPU runs it slowly inside the backward pass: 36 ms against 21 ms for
    the first two conv layers of a 32 × 9 batch, issue 7.)
    """
    return x @ w + b


def _affine_fwd(x: jax.Array, w: jax.Array, b: jax.Array) -> tuple[jax.Array, tuple]:
    return x @ w + b, (x, w)


def _affine_bwd(res: tuple, g: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    x, w = res
    # the ones join the 2-D rows: joined to x before the reshape, XLA allocates
    # about a quarter more temporaries for the smoke config's update
    rows = _rows(x)
    rows = jnp.concatenate([rows, jnp.ones((rows.shape[0], 1), rows.dtype)], axis=1)
    grad_wb = _rows_product(rows, g)  # (n_in + 1, n_out)
    return g @ w.T, grad_wb[:-1], grad_wb[-1]


affine.defvjp(_affine_fwd, _affine_bwd)


@jax.custom_vjp
def matmul(x: jax.Array, w: jax.Array) -> jax.Array:
    """``x @ w``: (..., n_in) @ (n_in, n_out), its weight gradient by :func:`_rows_product`
    (autodiff's ``xᵀ g`` would depend on XLA:CPU's thread pool)."""
    return x @ w


def _matmul_fwd(x: jax.Array, w: jax.Array) -> tuple[jax.Array, tuple]:
    return x @ w, (x, w)


def _matmul_bwd(res: tuple, g: jax.Array) -> tuple[jax.Array, jax.Array]:
    x, w = res
    return g @ w.T, _rows_product(x, g)


matmul.defvjp(_matmul_fwd, _matmul_bwd)


def _glorot(key: jax.Array, shape: tuple[int, ...], fan_in: int, fan_out: int) -> jax.Array:
    """Glorot-uniform weights of ``shape``.

    Drawn flat and reshaped: the same bits as drawing ``shape`` directly (the
    threefry counter is the row-major index), but a 4-D draw compiles 10 × slower
    on XLA:CPU (about 2 s for a conv kernel, against 0.2 s flat).
    """
    limit = math.sqrt(6.0 / (fan_in + fan_out))
    flat = jax.random.uniform(key, (math.prod(shape),), jnp.float32, -limit, limit)
    return flat.reshape(shape)


def _dense_init(key: jax.Array, n_in: int, n_out: int, norm: bool = False) -> Params:
    """Glorot weights and zero bias; with ``norm``, a LayerNorm's scale (ones) and
    bias (zeros) under ``"norm"``."""
    layer = {"w": _glorot(key, (n_in, n_out), n_in, n_out), "b": jnp.zeros((n_out,), jnp.float32)}
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


def _lstm_init(key: jax.Array, n_in: int, n_hidden: int) -> Params:
    """Weights of [x, h] -> 4 gates (i, f, g, o); forget bias 1."""
    w = _glorot(key, (n_in + n_hidden, 4 * n_hidden), n_in + n_hidden, n_hidden)
    b = jnp.zeros((4, n_hidden), jnp.float32).at[1].set(1.0).reshape(-1)
    return {"w": w, "b": b}


def lstm_cell(p: Params, x: jax.Array, state: LSTMState) -> tuple[jax.Array, LSTMState]:
    """One LSTM step.

    Args:
        p: ``{"w": (n_in + H, 4H), "b": (4H,)}``; x: (..., n_in); state: ((..., H), (..., H)).
    Returns:
        h' (..., H) and the new state (h', c').
    """
    h, c = state
    return _lstm_gates(affine(jnp.concatenate([x, h], axis=-1), p["w"], p["b"]), c)


def _recurrent_layer(
    p: Params,
    x: jax.Array,
    extra: jax.Array | None,
    state: Any,
    resets: jax.Array,
    config: NetworkConfig,
) -> tuple[jax.Array, Any]:
    """One recurrent layer of ``config.cell`` (:data:`CELLS`) over a time-major sequence:
    outputs (T, B..., H) and the last state.

    The same function as :func:`lstm_cell` (:func:`gru_cell`) step by step on
    ``[x, extra]`` (``extra`` (T, B..., E) or None), with the state zeroed where
    ``resets`` (T, B...) is true; the input projection of every step is one matrix
    product before the ``lax.scan``, which multiplies only the recurrent state.
    """
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
        if config.cell == "gru":
            h, state = _gru_gates(gates, state[0], w_h, p["b_hn"])
        else:
            h, state = _lstm_gates(gates + matmul(state[0], w_h), state[1])
        return state, h

    unroll = min(x.shape[0], config.scan_unroll)
    state, h = jax.lax.scan(body, state, (x_gates, resets), unroll=unroll)
    return h, state


def _lstm_gates(gates: jax.Array, c: jax.Array) -> tuple[jax.Array, LSTMState]:
    """h' and (h', c') from the pre-activations (..., 4H) of the gates (i, f, g, o)."""
    i, f, g, o = jnp.split(gates, 4, axis=-1)
    c = jax.nn.sigmoid(f) * c + jax.nn.sigmoid(i) * jnp.tanh(g)
    h = jax.nn.sigmoid(o) * jnp.tanh(c)
    return h, (h, c)


def _gru_init(key: jax.Array, n_in: int, n_hidden: int) -> Params:
    """Weights of [x, h] -> 3 gates (r, z, n), their biases and the bias of h's part
    of n (flax's ``GRUCell`` layout); biases 0."""
    w = _glorot(key, (n_in + n_hidden, 3 * n_hidden), n_in + n_hidden, n_hidden)
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
    """One GRU step (the ``"gru"`` cell of :class:`NetworkConfig`).

    Args:
        p: ``{"w": (n_in + H, 3H), "b": (3H,), "b_hn": (H,)}``; x: (..., n_in);
            state: ((..., H),).
    Returns:
        h' (..., H) and the new state (h',).
    """
    n_in = x.shape[-1]
    return _gru_gates(affine(x, p["w"][:n_in], p["b"]), state[0], p["w"][n_in:], p["b_hn"])


def conv_torso(
    params: Params, grid: jax.Array, config: NetworkConfig, *, gather: bool = False
) -> jax.Array:
    """The conv stack on grids of any leading shape: (..., 45, 30, 4) -> (..., 64).

    Each layer multiplies its patches (exact copies) with the kernel as a matrix:
    ``vmap`` runs a ``conv_general_dilated`` over seeds as a grouped convolution
    that sums in another order (a run among others would drift from it alone).
    ``gather`` (acting) takes the first layer's patches from one gather; the
    update keeps slices, with a third fewer temporaries (paper: 47 MB, not 72).
    """
    lead = grid.shape[: grid.ndim - 3]
    x = grid.reshape((-1, *grid.shape[-3:]))
    for i, (layer, (kh, kw, stride, _)) in enumerate(zip(params["conv"], config.conv, strict=True)):
        patches = (_gathered_patches if gather and i == 0 else _patches)(x, kh, kw, stride)
        x = jax.nn.relu(affine(patches, _kernel_matrix(layer["w"]), layer["b"]))
    return x.reshape((*lead, config.features))


def _patches(x: jax.Array, kh: int, kw: int, stride: int) -> jax.Array:
    """(N, H, W, C) -> (N, H', W', kh·kw·C) VALID patches, by strided slices (exact copies)."""
    _, h, w, _ = x.shape
    h_out, w_out = (h - kh) // stride + 1, (w - kw) // stride + 1
    rows = [
        x[:, i : i + stride * (h_out - 1) + 1 : stride, j : j + stride * (w_out - 1) + 1 : stride]
        for i in range(kh)
        for j in range(kw)
    ]
    return jnp.concatenate(rows, axis=-1)


def _gathered_patches(x: jax.Array, kh: int, kw: int, stride: int) -> jax.Array:
    """:func:`_patches` as one gather of the same copies: on XLA:CPU much faster than the
    paper network's 48 slices (``benchmarks/RESULTS.md``, "``drqn-jax reproduce`` wall
    time"), but its gradient (a scatter-add) sums in another order: acting only."""
    n, h, w, c = x.shape
    h_out, w_out = (h - kh) // stride + 1, (w - kw) // stride + 1
    rows = np.arange(h_out)[:, None, None, None] * stride + np.arange(kh)[None, None, :, None]
    cols = np.arange(w_out)[None, :, None, None] * stride + np.arange(kw)[None, None, None, :]
    index = ((rows * w + cols)[..., None] * c + np.arange(c)).reshape(-1)  # (H'·W'·kh·kw·C,)
    return x.reshape(n, h * w * c)[:, index].reshape(n, h_out, w_out, kh * kw * c)


def _kernel_matrix(w: jax.Array) -> jax.Array:
    """(kh, kw, C, F) kernel as the (kh·kw·C, F) matrix matching :func:`_patches`."""
    return w.reshape(-1, w.shape[-1])


def mlp_torso(params: Params, obs: jax.Array) -> jax.Array:
    """Dense ReLU layers on flat observations of any leading shape: (..., n) -> (..., width)."""
    x = obs.astype(jnp.float32)
    for layer in params["torso"]:
        x = dense_relu(layer, x)
    return x


def _extra_inputs(obs: Observation, num_actions: int) -> jax.Array:
    """``[speed, one-hot last action]`` (..., 1 + A); a last action of -1 is all zeros."""
    one_hot = jax.nn.one_hot(obs.last_action, num_actions, dtype=jnp.float32)
    return jnp.concatenate([obs.speed[..., None].astype(jnp.float32), one_hot], axis=-1)


def _stacked(seen: jax.Array) -> jax.Array:
    """(..., k, rows, cols, C) grids, oldest first -> (..., rows, cols, k·C)."""
    moved = jnp.moveaxis(seen, -4, -2)  # (..., rows, cols, k, C)
    return moved.reshape((*moved.shape[:-2], -1))


def _stack_sequence(
    grid: jax.Array, carry: jax.Array, resets: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """The stacked grids (T, B..., rows, cols, k·C) of a time-major sequence
    (T, B..., rows, cols, C) whose k − 1 grids before are ``carry`` (B..., k − 1,
    …), and the carry after it. A grid before the latest reset at or before t
    (an episode's start) is zeros in step t's stack, as :meth:`step` sees it
    after a reset carry."""
    k = carry.shape[-4] + 1
    steps = grid.shape[0]
    before = jnp.moveaxis(carry, -4, 0)  # (k - 1, B..., rows, cols, C)
    frames = jnp.concatenate([before, grid])  # (k - 1 + T, B..., …)
    t = jnp.arange(steps)
    lead = resets.shape[1:]
    index = jnp.broadcast_to(t.reshape((steps,) + (1,) * len(lead)), resets.shape)
    last_reset = jax.lax.cummax(jnp.where(resets, index, -steps - k), axis=0)  # (T, B...)
    stacked = []
    for j in range(k):  # frame t - (k - 1) + j of step t
        when = index - (k - 1) + j
        keep = (when >= last_reset)[..., None, None, None]
        stacked.append(jnp.where(keep, frames[j : j + steps], 0.0))
    seen = jnp.stack(stacked, axis=-4)  # (T, B..., k, rows, cols, C)
    return _stacked(seen), seen[-1, ..., 1:, :, :, :]


def _recurrent_names(config: NetworkConfig) -> tuple[str, str]:
    """The recurrent layers' parameter names (the paper's LSTMs keep the names of
    every checkpoint written before the GRU)."""
    return ("lstm1", "lstm2") if config.cell == "lstm" else ("gru1", "gru2")


def _init_torso(config: NetworkConfig, keys: jax.Array) -> Params:
    """The torso's parameters: ``{"conv": [{"w": (kh, kw, C_in, F), "b": (F,)}, ...]}``
    or ``{"torso": [dense, ...]}`` for the MLP torso; one key per layer."""
    if config.torso != "conv":
        widths = (config.obs_size, *config.mlp)
        return {
            "torso": [
                _dense_init(k, n_in, n_out, config.layer_norm)
                for k, n_in, n_out in zip(keys, widths[:-1], widths[1:], strict=False)
            ]
        }
    layers, c_in = [], config.grid_shape[2] * config.frames
    for k, (kh, kw, _, filters) in zip(keys, config.conv, strict=False):
        fan_in, fan_out = kh * kw * c_in, kh * kw * filters
        layers.append(
            {
                "w": _glorot(k, (kh, kw, c_in, filters), fan_in, fan_out),
                "b": jnp.zeros((filters,), jnp.float32),
            }
        )
        c_in = filters
    return {"conv": layers}


def _init_params(config: NetworkConfig, key: jax.Array) -> Params:
    """Fresh parameters of the network ``config`` describes (its ``init``)."""
    width, n_extra = config.recurrent, config.extra_inputs
    n_torso = len(config.conv) if config.torso == "conv" else len(config.mlp)
    keys = jax.random.split(key, n_torso + 4)
    k1, k2, k3, k4 = keys[n_torso:]
    if config.kind == "drqn":
        cell_init = _lstm_init if config.cell == "lstm" else _gru_init
        first, second = _recurrent_names(config)
        core = {
            first: cell_init(k1, config.features, width),
            second: cell_init(k2, width + n_extra, width),
        }
    else:
        core = {
            "dense1": _dense_init(k1, config.features, width),
            "dense2": _dense_init(k2, width + n_extra, width),
        }
    return {
        **_init_torso(config, keys[:n_torso]),
        **core,
        "fc": _dense_init(k3, width, config.hidden, config.layer_norm),
        "q": _dense_init(k4, config.hidden, config.num_actions),
    }


@cached_program
def make_network(config: NetworkConfig | None = None) -> Network:
    """Build the pure functions of a DRQN (or DQN) for ``config`` (once per config:
    the same config gives the same functions, so ``jit`` reuses their compilations)."""
    config = NetworkConfig() if config is None else config
    width, n_act = config.recurrent, config.num_actions
    conv = config.torso == "conv"

    frames = config.frames
    layers = _recurrent_names(config)  # and the cell's step function
    cell = lstm_cell if config.cell == "lstm" else gru_cell

    def initial_carry(batch_shape: tuple[int, ...] = ()) -> Carry:
        if config.kind == "dqn":
            return () if frames == 1 else jnp.zeros((*batch_shape, frames - 1, *config.grid_shape))
        zeros = jnp.zeros((*batch_shape, width), jnp.float32)
        if config.cell == "gru":
            return ((zeros,), (zeros,))
        return ((zeros, zeros), (zeros, zeros))

    def core(params: Params, features: jax.Array, extra: jax.Array, carry: Carry):
        """The recurrent (or dense) part for one time step: LSTM2's (or dense2's)
        output (..., H) and the new carry."""
        if config.kind == "drqn":
            h1, s1 = cell(params[layers[0]], features, carry[0])
            h2, s2 = cell(params[layers[1]], jnp.concatenate([h1, extra], -1), carry[1])
            return h2, (s1, s2)
        h1 = jax.nn.relu(affine(features, params["dense1"]["w"], params["dense1"]["b"]))
        x2 = jnp.concatenate([h1, extra], -1)
        return jax.nn.relu(affine(x2, params["dense2"]["w"], params["dense2"]["b"])), carry

    def head(params: Params, h2: jax.Array) -> jax.Array:
        """Q-values (..., A) of the core's outputs (..., H): FC + ReLU, then linear."""
        return affine(dense_relu(params["fc"], h2), params["q"]["w"], params["q"]["b"])

    def core_step(params: Params, features: jax.Array, extra: jax.Array, carry: Carry):
        """The core and the head for one time step."""
        h2, carry = core(params, features, extra, carry)
        return head(params, h2), carry

    def inputs(params: Params, obs: Any, gather: bool) -> tuple[jax.Array, jax.Array]:
        """The torso's features and the extra inputs of unstacked observations."""
        if not conv:
            features = mlp_torso(params, obs)
            return features, features[..., :0]
        return conv_torso(params, obs.grid, config, gather=gather), _extra_inputs(obs, n_act)

    def step(params: Params, obs: Any, carry: Carry) -> tuple[jax.Array, Carry]:
        """Q-values (..., A) for one time step with any leading batch shape (acting:
        the first conv layer's patches gathered, see :func:`conv_torso`)."""
        if not conv or frames == 1:
            return core_step(params, *inputs(params, obs, gather=True), carry)
        grid = obs.grid
        # the carry holds the grids before: stack, keep the newest k - 1
        seen = jnp.concatenate([carry, grid[..., None, :, :, :]], axis=-4)
        grid, carry = _stacked(seen), seen[..., 1:, :, :, :]
        features = conv_torso(params, grid, config, gather=True)
        return core_step(params, features, _extra_inputs(obs, n_act), carry)

    def unroll(
        params: Params, obs_seq: Any, carry: Carry, resets: jax.Array
    ) -> tuple[jax.Array, Carry]:
        """Q-values (T, B..., A) over a time-major sequence.

        The torso, each recurrent layer's input projection and the head run on
        all T·B steps at once; each recurrent layer is a ``lax.scan`` over T of
        its recurrent product alone (:func:`_recurrent_layer`), its state zeroed
        where ``resets`` (T, B...) is true. The same function as :meth:`step` step by step (sums
        in another order: equal to float32 rounding).
        """
        if frames > 1:  # the stacking does the resets; the dense core has no carry
            grid, carry = _stack_sequence(obs_seq.grid, carry, resets)
            features = conv_torso(params, grid, config)  # (T, B..., F)
            q, _ = core_step(params, features, _extra_inputs(obs_seq, n_act), ())
            return q, carry
        features, extra = inputs(params, obs_seq, gather=False)
        if config.kind == "dqn":  # no carry: every step at once
            return core_step(params, features, extra, carry)
        first, second = carry
        h1, first = _recurrent_layer(params[layers[0]], features, None, first, resets, config)
        h2, second = _recurrent_layer(params[layers[1]], h1, extra, second, resets, config)
        return head(params, h2), (first, second)

    return Network(
        config=config,
        init=functools.partial(_init_params, config),
        initial_carry=initial_carry,
        step=step,
        unroll=unroll,
    )


def param_count(params: Params) -> int:
    """Number of scalars in a parameter pytree."""
    return sum(int(x.size) for x in jax.tree.leaves(params))
