"""The DRQN of paper §V-A (Table I, Fig. 3) and a DQN ablation, as plain pytrees (SPEC §7).
Conv 8×6/4 (32) → 4×3/3 (64) → 2×2/2 (64), ReLU, VALID (45×30 → 1×1, 64 features);
``drqn``: LSTM1 (256) → LSTM2 (256) fed ``[h1, speed, one-hot last action]``; ``dqn``:
two dense ReLU layers instead (``frames`` = k > 1: the last k grids stacked); FC 256
ReLU → 4 Q-values. Flat-vector envs get an MLP torso (``torso = "mlp"``) and no extras."""

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.env.state import NUM_ACTIONS, Observation
from drqn_jax.layers import (
    Params,
    affine,
    dense_init,
    dense_relu,
    gathered_patches,
    glorot,
    gru_cell,
    gru_init,
    kernel_matrix,
    lstm_cell,
    lstm_init,
    patches,
    recurrent_layer,
    stack_sequence,
    stacked,
)
from drqn_jax.programs import cached_program
from drqn_jax.pytree import check_counts

Carry = Any

NETWORK_KINDS = ("drqn", "dqn")
#: The recurrent cells of kind ``drqn``: the paper's LSTM (Table I) and a GRU.
CELLS = ("lstm", "gru")
#: What reads the observation: Table I's conv stack (grids) or an MLP (flat vectors).
TORSOS = ("conv", "mlp")


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Shape-setting settings of the Q-network (hashable): ``conv`` (kernel_h, kernel_w, stride,
    filters) per layer; ``recurrent`` core and ``hidden`` FC widths; ``frames`` stacked (``dqn``);
    ``torso`` ``"conv"`` or ``"mlp"``; ``layer_norm`` before the MLP's and FC's ReLUs (PQN's);
    ``cell`` ``"lstm"`` (Table I) or ``"gru"``; ``scan_unroll``: ``lax.scan``'s (same bits)."""

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
        for name, choices in (("kind", NETWORK_KINDS), ("cell", CELLS), ("torso", TORSOS)):
            if getattr(self, name) not in choices:
                value = getattr(self, name)
                raise ValueError(f"NetworkConfig.{name} = {value!r}: must be one of {choices}")
        if self.cell != "lstm" and self.kind != "drqn":
            raise ValueError(
                f"NetworkConfig.cell = {self.cell!r}: a cell is for kind 'drqn'; use 'lstm'"
            )
        if self.torso == "mlp" and (
            self.obs_size < 1 or any(not isinstance(w, int) or w < 1 for w in self.mlp)
        ):
            raise ValueError(
                f"NetworkConfig.mlp = {self.mlp!r}, obs_size = {self.obs_size!r}: the MLP "
                "torso needs integer widths >= 1 and a flat observation of >= 1 floats"
            )
        check_counts(self, ("recurrent", "hidden", "frames", "num_actions", "scan_unroll"))
        if self.frames > 1 and (self.kind != "dqn" or self.torso != "conv"):
            raise ValueError(
                f"NetworkConfig.frames = {self.frames}: stacking grids is for kind 'dqn' "
                "with torso 'conv'; use 1"
            )
        if self.torso == "conv" and any(min(layer) < 1 for layer in self.conv):
            raise ValueError(f"NetworkConfig.conv = {self.conv!r}: all sizes must be >= 1")
        if self.torso == "conv" and min(self.conv_output_shape[:2]) < 1:
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
        """Width of the torso's output (64 for Table I)."""
        if self.torso == "mlp":
            return self.mlp[-1] if self.mlp else self.obs_size
        return math.prod(self.conv_output_shape)

    @property
    def extra_inputs(self) -> int:
        """Width of LSTM2's extra inputs: speed + one-hot last action (conv), else 0."""
        return 1 + self.num_actions if self.torso == "conv" else 0


class Network(NamedTuple):
    """Pure functions of one Q-network: ``init(key)``, ``initial_carry(batch_shape)``,
    ``step(params, obs, carry) -> (q, carry)`` (acting, any batch shape) and
    ``unroll(params, obs_seq, carry, resets)`` over time-major (T, B, …) sequences."""

    config: NetworkConfig
    init: Callable[[jax.Array], Params]
    initial_carry: Callable[[tuple[int, ...]], Carry]
    step: Callable[[Params, Observation, Carry], tuple[jax.Array, Carry]]
    unroll: Callable[[Params, Observation, Carry, jax.Array], tuple[jax.Array, Carry]]


def conv_torso(
    params: Params, grid: jax.Array, config: NetworkConfig, *, gather: bool = False
) -> jax.Array:
    """The conv stack as patch products: (..., 45, 30, 4) -> (..., 64); ``gather``
    (acting only) takes the first layer's patches from one gather."""
    lead = grid.shape[: grid.ndim - 3]
    x = grid.reshape((-1, *grid.shape[-3:]))
    for i, (layer, (kh, kw, stride, _)) in enumerate(zip(params["conv"], config.conv, strict=True)):
        x_patches = (gathered_patches if gather and i == 0 else patches)(x, kh, kw, stride)
        x = jax.nn.relu(affine(x_patches, kernel_matrix(layer["w"]), layer["b"]))
    return x.reshape((*lead, config.features))


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


def _init_torso(config: NetworkConfig, keys: jax.Array) -> Params:
    """``{"conv": [{"w": (kh, kw, C_in, F), "b": (F,)}, ...]}`` or ``{"torso": [...]}``."""
    if config.torso != "conv":
        widths = (config.obs_size, *config.mlp)
        return {
            "torso": [
                dense_init(k, n_in, n_out, config.layer_norm)
                for k, n_in, n_out in zip(keys, widths[:-1], widths[1:], strict=False)
            ]
        }
    layers, c_in = [], config.grid_shape[2] * config.frames
    for k, (kh, kw, _, filters) in zip(keys, config.conv, strict=False):
        w = glorot(k, (kh, kw, c_in, filters), kh * kw * c_in, kh * kw * filters)
        layers.append({"w": w, "b": jnp.zeros((filters,), jnp.float32)})
        c_in = filters
    return {"conv": layers}


def _init_params(config: NetworkConfig, key: jax.Array) -> Params:
    """Fresh parameters of the network ``config`` describes (its ``init``)."""
    width, n_extra = config.recurrent, config.extra_inputs
    n_torso = len(config.conv) if config.torso == "conv" else len(config.mlp)
    keys = jax.random.split(key, n_torso + 4)
    k1, k2, k3, k4 = keys[n_torso:]
    if config.kind == "drqn":  # lstm1/2 or gru1/2
        init = lstm_init if config.cell == "lstm" else gru_init
        names = (f"{config.cell}1", f"{config.cell}2")
    else:
        init, names = dense_init, ("dense1", "dense2")
    core = {names[0]: init(k1, config.features, width), names[1]: init(k2, width + n_extra, width)}
    return {
        **_init_torso(config, keys[:n_torso]),
        **core,
        "fc": dense_init(k3, width, config.hidden, config.layer_norm),
        "q": dense_init(k4, config.hidden, config.num_actions),
    }


@cached_program
def make_network(config: NetworkConfig | None = None) -> Network:
    """The pure functions of a DRQN (or DQN), cached per config so ``jit`` reuses them."""
    config = NetworkConfig() if config is None else config
    width, n_act, frames = config.recurrent, config.num_actions, config.frames
    conv = config.torso == "conv"
    layers = (f"{config.cell}1", f"{config.cell}2")  # their parameters: lstm1/2 or gru1/2
    cell = lstm_cell if config.cell == "lstm" else gru_cell

    def initial_carry(batch_shape: tuple[int, ...] = ()) -> Carry:
        if config.kind == "dqn":
            return () if frames == 1 else jnp.zeros((*batch_shape, frames - 1, *config.grid_shape))
        zeros = jnp.zeros((*batch_shape, width), jnp.float32)
        state = (zeros,) if config.cell == "gru" else (zeros, zeros)  # (h,) or (h, c)
        return (state, state)

    def head(params: Params, h2: jax.Array) -> jax.Array:
        """Q-values (..., A) of the core's outputs (..., H): FC + ReLU, then linear."""
        return affine(dense_relu(params["fc"], h2), params["q"]["w"], params["q"]["b"])

    def core_step(params: Params, features: jax.Array, extra: jax.Array, carry: Carry):
        """The recurrent (or dense) core and the head for one time step: Q-values, carry."""
        if config.kind == "drqn":
            h1, s1 = cell(params[layers[0]], features, carry[0])
            h2, s2 = cell(params[layers[1]], jnp.concatenate([h1, extra], -1), carry[1])
            return head(params, h2), (s1, s2)
        h1 = dense_relu(params["dense1"], features)
        return head(params, dense_relu(params["dense2"], jnp.concatenate([h1, extra], -1))), carry

    def inputs(params: Params, obs: Any, gather: bool) -> tuple[jax.Array, jax.Array]:
        """The torso's features and the extra inputs of unstacked observations."""
        if not conv:
            features = mlp_torso(params, obs)
            return features, features[..., :0]
        return conv_torso(params, obs.grid, config, gather=gather), _extra_inputs(obs, n_act)

    def step(params: Params, obs: Any, carry: Carry) -> tuple[jax.Array, Carry]:
        """Q-values (..., A) for one time step, any leading batch shape (acting)."""
        if not conv or frames == 1:
            return core_step(params, *inputs(params, obs, gather=True), carry)
        grid = obs.grid
        # the carry holds the grids before: stack, keep the newest k - 1
        seen = jnp.concatenate([carry, grid[..., None, :, :, :]], axis=-4)
        grid, carry = stacked(seen), seen[..., 1:, :, :, :]
        features = conv_torso(params, grid, config, gather=True)
        return core_step(params, features, _extra_inputs(obs, n_act), carry)

    def unroll(
        params: Params, obs_seq: Any, carry: Carry, resets: jax.Array
    ) -> tuple[jax.Array, Carry]:
        """Q-values (T, B..., A) over a time-major sequence, the carry zeroed where
        ``resets`` (T, B...); :meth:`step` step by step up to float32 rounding."""
        if frames > 1:  # the stacking does the resets; the dense core has no carry
            grid, carry = stack_sequence(obs_seq.grid, carry, resets)
            features = conv_torso(params, grid, config)  # (T, B..., F)
            q, _ = core_step(params, features, _extra_inputs(obs_seq, n_act), ())
            return q, carry
        features, extra = inputs(params, obs_seq, gather=False)
        if config.kind == "dqn":  # no carry: every step at once
            return core_step(params, features, extra, carry)
        first, second = carry
        cell, n = config.cell, config.scan_unroll
        h1, first = recurrent_layer(params[layers[0]], features, None, first, resets, cell, n)
        h2, second = recurrent_layer(params[layers[1]], h1, extra, second, resets, cell, n)
        return head(params, h2), (first, second)

    return Network(
        config=config,
        init=functools.partial(_init_params, config),
        initial_carry=initial_carry,
        step=step,
        unroll=unroll,
    )
