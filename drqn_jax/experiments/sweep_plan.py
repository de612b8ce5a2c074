"""A sweep's plan (SPEC §7): which points train together in which compiled **call**, on which
devices and processes. Points are grouped into programs by shape; each process takes a contiguous
slice of every program, cut into padded calls by the memory plan, made before anything compiles:
a run's ``TrainState`` (exact, via ``jax.eval_shape``) plus one gradient update's temporaries
(estimated from layer sizes, within 1-2× of XLA's ``memory_analysis()``)."""

import dataclasses
import hashlib
import itertools
import json
import math
import os
from collections.abc import Sequence
from typing import Any

import jax

from drqn_jax.config import Config, ConfigError
from drqn_jax.experiments.sweep import Sweep, SweepPoint
from drqn_jax.learners.hyperparams import ON_POLICY


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


# ------------------------------------------------------------------------ the memory plan

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
    return sum(math.prod(x.shape) * x.dtype.itemsize for x in jax.tree.leaves(tree))


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
    return int(ACTIVATION_FACTOR * samples * floats * 4)  # float32


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


def available_memory(devices: Sequence[Any]) -> tuple[int, str]:
    """Bytes the ``devices`` can hold (accelerator limit minus use, or host ``MemAvailable``,
    0 where unknown) and where the figure comes from."""
    if all(d.platform == "cpu" for d in devices):
        try:
            with open("/proc/meminfo") as f:
                lines = [line.split() for line in f if line.startswith("MemAvailable:")]
            return int(lines[0][1]) * 1024, "host MemAvailable"
        except (OSError, IndexError):
            return 0, "host MemAvailable"
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
    """Runs per compiled call: a multiple of ``devices``, at most ``runs`` rounded up, one
    per device unless ``batched`` (one after another gains nothing from a bigger call, and
    a call's runs save their results only when all have ended); MemoryPlanError if not one
    run per device fits ``budget``."""
    usable = USABLE_FRACTION * budget
    need = devices * call_bytes(per_run, 1, batched=batched)
    if need > usable:
        raise MemoryPlanError(
            f"memory plan: one run needs {per_run.describe()}; {devices} device(s) need "
            f"{format_bytes(need)} but {format_bytes(usable)} is usable "
            f"({USABLE_FRACTION:.0%} of {format_bytes(budget)}, {source}). Reduce "
            "train.replay_episodes, train.batch_size, train.window or the network, "
            "or give --memory-gb"
        )
    if not batched:
        return devices
    return min(math.ceil(runs / devices), math.floor(usable / devices / per_run.total)) * devices


# ---------------------------------------------------------------------------- the calls


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
    """This process's calls, in order: its slice of every program, cut to fit ``budget`` (with
    ``map`` one run per device, so runs finish and are saved one by one); MemoryPlanError if one
    run per device does not fit."""
    local = jax.local_devices()[:devices]
    strategy = resolve_strategy(sweep.strategy if strategy is None else strategy, local)
    if budget is None:
        budget, memory_source = available_memory(local)
    calls = []
    for k, program in enumerate(sweep.programs()):
        bounds = [len(program) * i // dist.processes for i in range(dist.processes + 1)]
        mine = program[bounds[dist.process] : bounds[dist.process + 1]]  # contiguous, near-equal
        if not mine:
            continue
        memory = run_memory(mine[0].config)
        batched = strategy == "vmap"
        most = runs_per_call(memory, len(mine), devices, budget, memory_source, batched=batched)
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
