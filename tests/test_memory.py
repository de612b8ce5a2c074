"""The memory plan's per-run estimate against XLA's own analysis of the compiled program."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest

from drqn_jax.config import load_config
from drqn_jax.memory import (
    MemoryPlanError,
    RunMemory,
    call_bytes,
    format_bytes,
    run_memory,
    runs_per_call,
)
from drqn_jax.sweep_runner import call_programs
from drqn_jax.train import make_train
from tests.helpers import SMOKE_SWEEP_SET


def test_the_estimate_covers_what_xla_allocates():
    """Paper preset: state bytes are exact; the estimated temporaries lie within
    1–2× of XLA's ``memory_analysis()`` of the compiled training chunk."""
    config = load_config("paper")
    trainer = make_train(config.train_config())
    state = jax.eval_shape(trainer.init, config.keys()[0])
    compiled = jax.jit(trainer.run, static_argnums=1).lower(state, 4).compile()
    xla = compiled.memory_analysis()
    estimate = run_memory(config)
    state_bytes = estimate.total - estimate.activations
    assert state_bytes == xla.argument_size_in_bytes
    assert xla.temp_size_in_bytes <= estimate.activations <= 2 * xla.temp_size_in_bytes


@pytest.mark.parametrize("strategy", ["map", "vmap"])
def test_the_call_estimate_covers_what_xla_allocates(strategy):
    """A 4-run call of test_sweep's smoke config: :func:`call_bytes` against XLA's
    peak (arguments + temporaries of the donating chunk program), within 1–2×."""
    config = load_config("smoke", list(SMOKE_SWEEP_SET))
    trainer = make_train(config.train_config())
    devices = jax.devices()[:1]
    init, run = call_programs(trainer, 4, devices, strategy)
    keys = jax.random.split(config.keys()[0], 4)
    hparams = jax.tree.map(lambda x: jnp.stack([jnp.asarray(x)] * 4), config.hyperparams())
    env_params = jax.tree.map(lambda x: jnp.stack([jnp.asarray(x)] * 4), config.make_env()[1])
    state = jax.eval_shape(init, keys, hparams, env_params)
    xla = run.lower(state, jax.ShapeDtypeStruct((4,), bool)).compile().memory_analysis()
    peak = xla.argument_size_in_bytes + xla.temp_size_in_bytes
    estimate = call_bytes(run_memory(config), 4, batched=strategy == "vmap")
    assert peak <= estimate <= 2 * peak


def test_runs_per_call_is_a_multiple_of_the_devices_or_refuses():
    per_run = RunMemory(replay=600, params=200, optimiser=200, other_state=0, activations=1000)
    assert runs_per_call(per_run, 64, 4, budget=int(20_000 / 0.8), source="test") == 8
    assert runs_per_call(per_run, 3, 4, budget=10**9, source="test") == 4
    with pytest.raises(MemoryPlanError, match=r"one run needs 2 kB .*replay 600 B"):
        runs_per_call(per_run, 8, 4, budget=4_000, source="test")
    assert format_bytes(28_466_074) == "28.5 MB"
