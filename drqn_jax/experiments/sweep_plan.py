"""A sweep's plan (SPEC §7): which points train together in which compiled **call**, on
which devices and processes. Points are grouped into programs by shape; each process takes
a contiguous slice of every program, cut by the memory plan into padded calls.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import os
from collections.abc import Sequence
from typing import Any

import jax

from drqn_jax.config import ConfigError
from drqn_jax.experiments.memory import (
    RunMemory,
    available_memory,
    call_bytes,
    format_bytes,
    run_memory,
    runs_per_call,
)
from drqn_jax.experiments.sweep import Sweep, SweepPoint

__all__ = [
    "Call",
    "Distributed",
    "call_size",
    "describe_plan",
    "init_distributed",
    "plan_calls",
    "resolve_strategy",
]


@dataclasses.dataclass(frozen=True)
class Distributed:
    """This process's place among the processes of a sweep (1 of 1 when alone)."""

    process: int = 0
    processes: int = 1

    @property
    def leader(self) -> bool:
        return self.process == 0


def init_distributed(
    coordinator: str | None, num_processes: int | None, process_id: int | None
) -> Distributed:
    """``jax.distributed.initialize`` from the flags or ``JAX_*`` env vars (none: one process).
    Must run before any JAX computation."""
    coordinator = coordinator or os.environ.get("JAX_COORDINATOR_ADDRESS")
    given = [coordinator, num_processes, process_id]
    num_processes = _int_variable(num_processes, "JAX_NUM_PROCESSES")
    process_id = _int_variable(process_id, "JAX_PROCESS_ID")
    if (coordinator, num_processes, process_id) == (None, None, None):
        return Distributed()
    if None in (coordinator, num_processes, process_id):
        raise ConfigError(
            "several processes need all three of --coordinator HOST:PORT, --num-processes N "
            "and --process-id I (or JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES, "
            f"JAX_PROCESS_ID); got {given}"
        )
    if num_processes < 1 or not 0 <= process_id < num_processes:
        raise ConfigError(
            f"--num-processes = {num_processes}, --process-id = {process_id}: need "
            "num_processes >= 1 and 0 <= process_id < num_processes"
        )
    jax.distributed.initialize(coordinator, num_processes, process_id)
    return Distributed(process_id, num_processes)


def _int_variable(given: int | None, name: str) -> int | None:
    """``given``, else the environment variable ``name`` (an integer) where set."""
    if given is not None or name not in os.environ:
        return given
    try:
        return int(os.environ[name])
    except ValueError:
        raise ConfigError(f"{name} = {os.environ[name]!r}: must be an integer") from None


@dataclasses.dataclass(frozen=True)
class Call:
    """Runs of one program trained together by one compiled call."""

    program: int
    points: tuple[SweepPoint, ...]
    size: int  # runs in the call, padding included: a multiple of the device count
    strategy: str = "vmap"  # "vmap" or "map" (see STRATEGIES)
    memory: RunMemory | None = None  # per run, as planned

    @property
    def name(self) -> str:
        return f"runs-{self.points[0].index:04d}-{self.points[-1].index:04d}"

    def fingerprint(self) -> str:
        """What the call's checkpoint must match: its runs' training configs and size."""
        hashes = [p.config.training_hash() for p in self.points]
        text = json.dumps([self.size, self.strategy, hashes])
        return hashlib.sha256(text.encode()).hexdigest()


def _process_slice(points: Sequence[SweepPoint], dist: Distributed) -> list[SweepPoint]:
    """Contiguous, near-equal slices of ``points``, one per process."""
    n, p = len(points), dist.processes
    bounds = [n * i // p for i in range(p + 1)]
    return list(points[bounds[dist.process] : bounds[dist.process + 1]])


def resolve_strategy(strategy: str, devices: Sequence[Any]) -> str:
    """``vmap`` or ``map`` for ``strategy`` (one of STRATEGIES) on ``devices``."""
    if strategy == "auto":
        return "map" if all(d.platform == "cpu" for d in devices) else "vmap"
    return strategy


def plan_calls(
    sweep: Sweep,
    devices: int,
    dist: Distributed = Distributed(),
    budget: int | None = None,
    memory_source: str = "",
    strategy: str | None = None,
) -> list[Call]:
    """This process's calls, in order: its slice of every program, cut to fit ``budget``.

    With ``map`` a call holds one run per device, so runs finish (and are saved) one by one.
    Raises MemoryPlanError if one run per device does not fit.
    """
    local = jax.local_devices()[:devices]
    strategy = resolve_strategy(sweep.strategy if strategy is None else strategy, local)
    if budget is None:
        budget, memory_source = available_memory(local)
    calls = []
    for k, program in enumerate(sweep.programs()):
        mine = _process_slice(program, dist)
        if not mine:
            continue
        memory = run_memory(mine[0].config)
        batched = strategy == "vmap"
        most = runs_per_call(memory, len(mine), devices, budget, memory_source, batched=batched)
        if not batched:  # one after another gains nothing from a bigger call, and a call's
            most = min(most, devices)  # runs save their results only when all have ended
        count = math.ceil(len(mine) / most)  # calls of near-equal size: one compile
        per_call = math.ceil(len(mine) / count)
        size = call_size(per_call, devices, strategy, most // devices)
        for i in range(0, len(mine), per_call):
            calls.append(Call(k, tuple(mine[i : i + per_call]), size, strategy, memory))
    return calls


def call_size(runs: int, devices: int, strategy: str = "vmap", most_per_device: int = 2) -> int:
    """A call's size with padding: a multiple of ``devices``; for ``vmap`` at least 2 runs
    per device where memory allows (a batch of 1 compiles unbatched products that round
    differently, so a run would drift by an ulp)."""
    per_device = math.ceil(runs / devices)
    if strategy == "vmap":
        per_device = max(per_device, min(2, most_per_device))
    return per_device * devices


def describe_plan(calls: Sequence[Call], devices: int, dist: Distributed) -> str:
    """One line per (run of alike) calls: runs, padding, strategy, memory."""
    where = f"process {dist.process} of {dist.processes}, " if dist.processes > 1 else ""
    lines = [f"memory plan ({where}{devices} device(s)):"]
    groups = itertools.groupby(calls, lambda c: (c.program, len(c.points), c.size, c.strategy))
    for group in (list(alike) for _, alike in groups):
        call = group[0]
        pad = call.size - len(call.points)
        names = (
            call.name if len(group) == 1 else f"{len(group)} calls {call.name} … {group[-1].name}"
        )
        line = f"  program {call.program}, {names}: {len(call.points)} run(s)"
        line += f" + {pad} padding" if pad else ""
        line += " each" if len(group) > 1 else ""
        line += f", {call.strategy}"
        if call.strategy == "vmap" and call.size == devices:
            line += " (1 per device: rounds unlike batched runs)"
        if call.memory is not None:
            batched = call.strategy == "vmap"
            total = devices * call_bytes(call.memory, call.size // devices, batched=batched)
            line += f", {format_bytes(total)} in all; per run {call.memory.describe()}"
        lines.append(line)
    return "\n".join(lines)
