"""The memory plan's per-run estimate against XLA's own analysis of the compiled program."""

from __future__ import annotations

import jax
import pytest

from drqn_jax.config import load_config
from drqn_jax.experiments.sweep import load_sweep
from drqn_jax.experiments.sweep_plan import (
    MemoryPlanError,
    RunMemory,
    call_bytes,
    format_bytes,
    plan_calls,
    run_memory,
    runs_per_call,
)
from drqn_jax.experiments.sweep_runner import call_inputs, call_programs
from drqn_jax.learners import make_train
from tests.helpers import SMOKE_SWEEP, fast_jit


def test_the_estimate_covers_what_xla_allocates():
    """Paper preset: state bytes are exact; the estimated temporaries lie within
    1–2× of XLA's ``memory_analysis()`` of the compiled training chunk. The chunk
    is compiled, never run, without LLVM's optimisation (``FAST_COMPILE``: 5 s
    instead of 8): the sizes are XLA's buffer assignment, made before code
    generation, and were the same bytes at both levels when this was written."""
    config = load_config("paper")
    trainer = make_train(config.train_config())
    state = jax.eval_shape(trainer.init, config.keys()[0])
    compiled = fast_jit(trainer.run, static_argnums=1).lower(state, 4).compile()
    xla = compiled.memory_analysis()
    estimate = run_memory(config)
    state_bytes = estimate.total - estimate.activations
    assert state_bytes == xla.argument_size_in_bytes
    assert xla.temp_size_in_bytes <= estimate.activations <= 2 * xla.temp_size_in_bytes


@pytest.mark.parametrize("strategy", ["map", "vmap"])
def test_the_call_estimate_covers_what_xla_allocates(strategy, tmp_path):
    """The first call of test_sweep's sweep on one device (``map``: one run,
    ``vmap``: all 4): :func:`call_bytes` against XLA's peak (arguments +
    temporaries) of the donating chunk program, within 1–2×. The program is
    lowered from the call's own inputs, so it is the one the sweep compiles
    (JAX's persistent cache serves whichever test file runs later)."""
    path = tmp_path / "sweep.toml"
    path.write_text(SMOKE_SWEEP)
    devices = jax.devices()[:1]
    call = plan_calls(load_sweep(path), len(devices), budget=10**12, strategy=strategy)[0]
    assert call.size == (1 if strategy == "map" else 4)
    config = call.points[0].config
    init, run, _ = call_programs(make_train(config.train_config()), call.size, devices, strategy)
    args, real = call_inputs(call, devices)
    xla = run.lower(init(*args), real).compile().memory_analysis()
    peak = xla.argument_size_in_bytes + xla.temp_size_in_bytes
    estimate = call_bytes(run_memory(config), call.size, batched=strategy == "vmap")
    assert peak <= estimate <= 2 * peak


def test_runs_per_call_is_a_multiple_of_the_devices_or_refuses():
    per_run = RunMemory(replay=600, params=200, optimiser=200, other_state=0, activations=1000)
    assert runs_per_call(per_run, 64, 4, budget=int(20_000 / 0.8), source="test") == 8
    assert runs_per_call(per_run, 3, 4, budget=10**9, source="test") == 4
    with pytest.raises(MemoryPlanError, match=r"one run needs 2 kB .*replay 600 B"):
        runs_per_call(per_run, 8, 4, budget=4_000, source="test")
    assert format_bytes(28_466_074) == "28.5 MB"
