"""Memory plan of a sweep: bytes per training run, estimated before anything compiles.

A run holds its ``TrainState`` (exact, via ``jax.eval_shape``) plus one gradient update's
temporaries (estimated from layer sizes, within 1-2× of XLA's ``memory_analysis()``).
:func:`runs_per_call` turns that and the available memory into runs per compiled call.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from drqn_jax.config import Config, ConfigError
from drqn_jax.learners.hyperparams import ON_POLICY

__all__ = [
    "MemoryPlanError",
    "RunMemory",
    "available_memory",
    "call_bytes",
    "format_bytes",
    "run_memory",
    "runs_per_call",
]

FLOAT_BYTES = 4
#: Share of the available memory a plan may fill.
USABLE_FRACTION = 0.8
#: Temporaries per forward activation byte (online + target unroll, backward pass).
ACTIVATION_FACTOR = 2.0
#: Parameter-sized temporaries of one Adam step, in parameter bytes.
PARAM_TEMPORARIES = 4


class MemoryPlanError(ConfigError):
    """One run (per device) does not fit in the memory available."""


@dataclasses.dataclass(frozen=True)
class RunMemory:
    """Bytes of one training run, by what holds them."""

    replay: int
    params: int  # online + target networks (+ the snapshots of train.snapshots)
    optimiser: int  # Adam's two moments
    other_state: int  # env states, observations, LSTM carries, metrics, counters
    activations: int  # temporaries of one gradient update (estimated)

    @property
    def total(self) -> int:
        return sum(dataclasses.astuple(self))

    def describe(self) -> str:
        fields = dataclasses.fields(self)
        parts = ", ".join(f"{f.name} {format_bytes(getattr(self, f.name))}" for f in fields)
        return f"{format_bytes(self.total)} ({parts})"


def format_bytes(n: float) -> str:
    """``12.3 MB`` (decimal units)."""
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if abs(n) >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} B"


def _nbytes(tree: Any) -> int:
    total = 0
    for leaf in jax.tree.leaves(tree):
        if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            total += 2 * 4 * math.prod(leaf.shape)  # threefry key data: 2 × uint32
        else:
            total += math.prod(leaf.shape) * np.dtype(leaf.dtype).itemsize
    return total


def activation_bytes(config: Config) -> int:
    """Estimated temporaries of one gradient update (DQN minibatch or PPO rollout): per
    sample, one observation's forward activations (paper Table I layers): grid, conv
    patches and outputs, recurrent core (or ``dqn`` dense layers), FC layer, Q-values."""
    network = config.network_config()
    h, w, c = network.grid_shape
    c *= network.frames
    floats = h * w * c
    for kh, kw, stride, filters in network.conv:
        h, w = (h - kh) // stride + 1, (w - kw) // stride + 1
        floats += h * w * (kh * kw * c + filters)
        c = filters
    r = network.recurrent
    core = 2 * (6 * r) + r if network.kind == "drqn" else 2 * r
    floats += network.features + core + network.hidden + network.num_actions
    train = config["train"]
    if train["algorithm"] in ON_POLICY:
        samples = train["rollout_steps"] * train["num_envs"]
    else:
        samples = train["batch_size"] * (train["burn_in"] + train["window"] + 1)
    return int(ACTIVATION_FACTOR * (samples * floats * FLOAT_BYTES))


def run_memory(config: Config) -> RunMemory:
    """Bytes of one run of ``config``: the state exactly (shapes only), temporaries estimated."""
    from drqn_jax.learners import make_train  # late: train imports the env stack

    trainer = make_train(config.train_config())
    state = jax.eval_shape(trainer.init, config.keys()[0])
    replay = _nbytes(getattr(state, "replay", None))  # PPO's and PQN's states have none
    dqn_only = (getattr(state, "target", None), getattr(state, "snapshots", None))
    params = _nbytes((state.online, *dqn_only))
    optimiser = _nbytes(state.opt_state)
    other = _nbytes(state) - replay - params - optimiser
    activations = activation_bytes(config) + PARAM_TEMPORARIES * _nbytes(state.online)
    return RunMemory(replay, params, optimiser, other, activations)


def _host_available() -> int:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 0


def available_memory(devices: Sequence[Any]) -> tuple[int, str]:
    """Bytes the ``devices`` can hold (accelerator limit minus use, or host ``MemAvailable``)
    and where the figure comes from."""
    if all(d.platform == "cpu" for d in devices):
        return _host_available(), "host MemAvailable"
    total = 0
    for d in devices:
        stats = d.memory_stats() or {}
        total += int(stats.get("bytes_limit", 0)) - int(stats.get("bytes_in_use", 0))
    return total, f"{devices[0].platform} memory of {len(devices)} device(s)"


def call_bytes(per_run: RunMemory, runs: int, *, batched: bool = True) -> int:
    """Peak bytes of ``runs`` runs on one device: ``batched``, every state and temporary at
    once; else (``lax.map``) the states twice and one run's temporaries."""
    if batched:
        return runs * per_run.total
    return 2 * runs * (per_run.total - per_run.activations) + per_run.activations


def runs_per_call(
    per_run: RunMemory, runs: int, devices: int, budget: int, source: str, *, batched: bool = True
) -> int:
    """Runs per compiled call: a multiple of ``devices``, at most ``runs`` rounded up;
    MemoryPlanError if not one run per device fits ``budget``."""
    usable = USABLE_FRACTION * budget
    per_device = 0
    while per_device < math.ceil(runs / devices) and (
        call_bytes(per_run, per_device + 1, batched=batched) <= usable / devices
    ):
        per_device += 1
    if per_device < 1:
        need = devices * call_bytes(per_run, 1, batched=batched)
        raise MemoryPlanError(
            f"memory plan: one run needs {per_run.describe()}; {devices} device(s) need "
            f"{format_bytes(need)} but {format_bytes(usable)} is usable "
            f"({USABLE_FRACTION:.0%} of {format_bytes(budget)}, {source}). Reduce "
            "train.replay_episodes, train.batch_size, train.window or the network, "
            "or give --memory-gb"
        )
    return per_device * devices
