"""Sweep throughput: aggregate env steps/s and updates/s of R training runs in one program.

Usage::

    python -m benchmarks.sweep_throughput [--runs 1 4 16 64] [--iterations 20] [--repeats 3]
        [--sequential-runs 16] [--sharded-runs 4 16] [--strategy vmap|map] [--out DIR]
        [--quick]

(``python -m benchmarks.sweep_throughput`` from the repository root works too.)

Measured for the paper preset ``TrainConfig()`` (one env per run, replay of
M = 50 episodes, minibatch 32 windows × 8 steps, one gradient update per env
step), learning active throughout:

1. **Filling the replay.** ONE run is initialised with ``learning_starts``
   raised out of reach and acts (``trainer.run``, chunks of 1000 iterations)
   until it has recorded ``learning_starts`` = 4 episodes (whole chunks, so
   often more); then ``learning_starts`` is set back to 4
   (``train_throughput.fill_replay``).
   The R runs of a row are R copies of that filled state with different PRNG
   keys (``jax.random.split``), stacked on a leading run axis, so every run
   learns from the first timed iteration on and the runs diverge from there.
2. **One program per run count** (``--runs``): the program a sweep call runs
   (``drqn_jax.experiments.sweep_runner.call_programs`` with ``chunk_iterations`` = I: a
   ``shard_map`` over the devices, each device's runs batched with ``vmap``
   or one after another with ``lax.map``, ``--strategy``; default what the
   sweep picks, ``map`` on CPU), state donated; 1 run is the plain unbatched
   ``jax.jit(partial(trainer.run, num_iterations=I))``. After one warm-up
   call, ``--repeats`` timed calls, each continuing from the previous state;
   the best (shortest) counts. Aggregate env steps/s = R · I · num_envs / s,
   updates/s = R · I · updates_per_step / s. Compile time (lower + XLA
   compile) is reported apart.
3. **One after another** (``--sequential-runs`` S, default 16): the same S
   runs (the same S keys as the S-run row) with the 1-run program, each call
   continuing its own run: one "call" is the loop over the S runs, timed like
   a batched call (warm-up, best of ``--repeats``), so aggregate env steps/s
   = S · I · num_envs / (best loop s). For any other R, "one after another"
   is R × the 1-run call time, i.e. the 1-run throughput.
4. **One device against sharding over 2 host devices**
   (``--sharded-runs``): XLA fixes its device count when the backend starts,
   so a subprocess of this script (hidden ``--sharded-child``) runs with
   ``--xla_force_host_platform_device_count=2`` added to ``XLA_FLAGS`` (the
   ``--xla_cpu_max_isa=AVX`` that ``import drqn_jax`` sets is kept). It
   refills the replay (same seed: the same filled state), puts the R-run
   state on a ``NamedSharding(Mesh(devices, ("runs",)), PartitionSpec("runs"))``
   and times the same program with the run axis sharded; R is padded
   to a multiple of the device count with extra runs, and only the R asked
   for count in the throughput. It answers JSON on stdout. CPU only.
5. **Memory**: per run, the replay (``replay_bytes``) and online + target +
   Adam (sum of leaf ``nbytes``); per row, the whole R-run ``TrainState`` and
   XLA's ``memory_analysis()`` of the compiled R-run program (arguments,
   outputs, aliased = donated, temporaries; peak ≈ arguments + outputs −
   aliased + temporaries). For the 64-run sweep, also the program
   ``drqn_jax.experiments.sweep`` compiles, ``jit(vmap(trainer.train))`` over 64 keys,
   hyperparameters and env parameters (compiled, not run), against 24 GB and
   against this machine's ``/proc/meminfo``.

On an accelerator (``jax.default_backend() != "cpu"``) the report adds the
64-run / 1-run aggregate ratio (target ≥ 20×) and skips the sharded child.

``--quick`` swaps in ``train_throughput.QUICK_CONFIG`` (tiny network, 30-step
episodes), 5 iterations and 1 repeat, and no sharded child unless
``--sharded-runs`` is given: a smoke check of the script, not a measurement.
``--out DIR`` writes everything (``DIR/sweep_throughput.json`` and ``.md``).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import os
import resource
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

import drqn_jax  # noqa: F401  (sets XLA_FLAGS; no JAX computation runs before this import)
from drqn_jax.experiments.machine import machine_info
from drqn_jax.experiments.sweep_plan import resolve_strategy
from drqn_jax.experiments.sweep_runner import call_programs
from drqn_jax.learners import TrainConfig, Trainer, make_train
from drqn_jax.learners.dqn.replay import replay_bytes
from drqn_jax.learners.dqn.state import TrainState

if __package__ in (None, ""):  # python benchmarks/sweep_throughput.py: the root importable
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from benchmarks.harness import base_parser, compile_timed, report, time_calls
from benchmarks.train_throughput import (
    MB,
    QUICK_CONFIG,
    SWEEP_GB,
    SWEEP_RUNS,
    fill_replay,
    memory_of,
    stack,
    tree_bytes,
    verdict,
)

TARGET_BATCHED_RATIO = 0.9  # issue 6: S runs in one program >= 0.9 × the same runs in turn (CPU)
TARGET_GPU_SPEEDUP = 20.0  # issue 6: 64 runs in one program >= 20 × one run (GPU)
HOST_DEVICES = 2  # host devices of the sharded child
GB = 1e9


# --------------------------------------------------------------------------- pieces


def meminfo() -> dict[str, float | None]:
    """MemTotal and MemAvailable from /proc/meminfo, in GB (None where unreadable)."""
    out: dict[str, float | None] = {"mem_total_gb": None, "mem_available_gb": None}
    try:
        with open("/proc/meminfo", encoding="utf-8") as f:
            for line in f:
                name, _, value = line.partition(":")
                if name in ("MemTotal", "MemAvailable"):
                    out[f"mem_{name[3:].lower()}_gb"] = int(value.split()[0]) * 1024 / GB
    except OSError:
        pass
    return out


def run_keys(seed: int, runs: int) -> jax.Array:
    """The PRNG keys of the R runs of a row (the same for the batched and sequential S runs)."""
    return jax.random.split(jax.random.key(seed + 1), runs)


def copies(filled: TrainState, keys: jax.Array) -> list[TrainState]:
    """Fresh copies of the filled state, one per key (donation must not touch ``filled``)."""
    return [jax.tree.map(jnp.copy, filled.replace(key=k)) for k in keys]


def run_program(
    trainer: Trainer,
    runs: int,
    iterations: int,
    strategy: str,
    sharding: NamedSharding | None = None,
) -> Callable[[TrainState], TrainState]:
    """The jitted, donating program that advances the runs by ``iterations``: for 1
    unsharded run the plain ``jit(trainer.run)``; otherwise the program a sweep call
    runs (``drqn_jax.experiments.sweep_runner.call_programs``: ``shard_map`` over the devices,
    each device's runs batched with ``vmap`` or one after another with ``lax.map``)."""
    if runs == 1 and sharding is None:
        return jax.jit(functools.partial(trainer.run, num_iterations=iterations), donate_argnums=0)
    devices = list(sharding.mesh.devices.flat) if sharding is not None else jax.devices()[:1]
    chunked = make_train(dataclasses.replace(trainer.config, chunk_iterations=iterations))
    _, run = call_programs(chunked, runs, devices, strategy)
    runs_axis = NamedSharding(Mesh(np.asarray(devices), ("runs",)), PartitionSpec("runs"))
    real = jax.device_put(np.ones(runs, bool), runs_axis)
    return jax.jit(lambda state: run(state, real), donate_argnums=0)


Counters = tuple[np.ndarray, np.ndarray]  # host copies of (env_steps, grad_steps)


def counters(state: TrainState) -> Counters:
    """Host copies of the step counters (a donated state becomes unusable)."""
    return np.asarray(state.env_steps), np.asarray(state.grad_steps)


def check_progress(
    trainer: Trainer, before: Counters, after: TrainState, expected_iterations: int
) -> None:
    """Raise unless every run made ``expected_iterations`` env steps AND gradient updates."""
    env_steps, grad_steps = counters(after)
    env_done, grad_done = env_steps - before[0], grad_steps - before[1]
    config = trainer.config
    if np.any(env_done != expected_iterations * config.num_envs):
        raise RuntimeError(f"env steps per run {env_done.tolist()}: a run finished early?")
    if np.any(grad_done != expected_iterations * config.updates_per_step):
        raise RuntimeError(f"gradient steps per run {grad_done.tolist()}: learning not active?")


def throughput(trainer: Trainer, runs: int, iterations: int, seconds: float) -> dict[str, float]:
    """Aggregate env steps/s and updates/s of ``runs`` runs doing ``iterations`` in ``seconds``."""
    config = trainer.config
    return {
        "env_steps_per_s": runs * iterations * config.num_envs / seconds,
        "updates_per_s": runs * iterations * config.updates_per_step / seconds,
    }


def peak_mb(xla: dict[str, float] | None) -> float | None:
    """Arguments + outputs − aliased (donated) + temporaries of a compiled program, MB."""
    if xla is None:
        return None
    return xla["argument_mb"] + xla["output_mb"] - xla["alias_mb"] + xla["temp_mb"]


def progress(text: str) -> None:
    print(f"[{text}]", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- measurements


def bench_batched(
    trainer: Trainer,
    filled: TrainState,
    runs: int,
    args: argparse.Namespace,
    sharding: NamedSharding | None = None,
) -> tuple[dict[str, Any], jax.stages.Compiled]:
    """Compile and time the R-run program (sharded over ``sharding``'s devices if given);
    the figures and the compiled program."""
    keys = run_keys(args.seed, runs)
    program_runs = runs
    if sharding is not None:  # pad to a multiple of the device count with extra runs
        devices = sharding.mesh.devices.size
        program_runs = math.ceil(runs / devices) * devices
        extra = jax.random.split(jax.random.key(args.seed + 2), program_runs - runs)
        keys = jnp.concatenate([keys, extra])
    if program_runs == 1 and sharding is None:
        state = copies(filled, keys)[0]
    else:  # jnp.stack makes new buffers: donating them leaves ``filled`` alone
        state = stack([filled.replace(key=k) for k in keys])
    if sharding is not None:
        state = jax.device_put(state, sharding)
    state_mb = tree_bytes(state) / MB
    jitted = run_program(trainer, program_runs, args.iterations, args.strategy, sharding)
    compiled, lower_s, xla_s = compile_timed(jitted, state)
    before = counters(state)
    state, t = time_calls(compiled, state, args.repeats)
    check_progress(trainer, before, state, args.iterations * (args.repeats + 1))
    xla = memory_of(compiled)
    row = {
        "runs": runs,
        "program_runs": program_runs,
        "devices": 1 if sharding is None else int(sharding.mesh.devices.size),
        "output_devices": len(state.env_steps.sharding.device_set),
        "lower_s": lower_s,
        "xla_compile_s": xla_s,
        "compile_s": lower_s + xla_s,
        **t,
        **throughput(trainer, runs, args.iterations, t["run_s"]),
        "train_state_mb": state_mb,
        "xla_memory": xla,
        "peak_mb": peak_mb(xla),
    }
    where = "1 device" if sharding is None else f"sharded over {row['devices']} devices"
    progress(
        f"{runs} run(s) in one program, {where}: compile {lower_s + xla_s:.2f} s, best "
        f"{t['run_s']:.3f} s per {args.iterations} iterations, {row['env_steps_per_s']:.2f} env "
        f"steps/s in all, cores used per timed call "
        f"{', '.join(f'{c:.2f}' for c in t['cores_used_per_call'])}"
    )
    return row, compiled


def bench_sequential(
    trainer: Trainer,
    filled: TrainState,
    runs: int,
    args: argparse.Namespace,
    compiled: jax.stages.Compiled,
) -> dict[str, Any]:
    """The same ``runs`` runs one after another with ``compiled``, the 1-run program (one
    timed call = the loop over the runs, each continuing its own run)."""
    states = copies(filled, run_keys(args.seed, runs))

    def loop(states: list[TrainState]) -> list[TrainState]:
        return [compiled(s) for s in states]

    before = [counters(s) for s in states]
    states, t = time_calls(loop, states, args.repeats)
    for b, s in zip(before, states, strict=True):
        check_progress(trainer, b, s, args.iterations * (args.repeats + 1))
    row = {"runs": runs, **t, **throughput(trainer, runs, args.iterations, t["run_s"])}
    progress(
        f"{runs} runs one after another (1-run program): best {t['run_s']:.3f} s per loop of "
        f"{args.iterations} iterations each, {row['env_steps_per_s']:.2f} env steps/s in all, "
        f"cores used per timed loop {', '.join(f'{c:.2f}' for c in t['cores_used_per_call'])}"
    )
    return row


def fill(trainer: Trainer, seed: int) -> tuple[TrainState, dict[str, Any]]:
    """One run's replay filled up to ``learning_starts`` episodes, learning then on."""
    fill_run = jax.jit(trainer.run, static_argnums=1, donate_argnums=0)
    episodes = int(trainer.config.hyperparams.learning_starts)
    filled, info = fill_replay(trainer, jax.random.key(seed), episodes, fill_run)
    progress(
        f"fill: {info['recorded']} episodes, {info['env_steps']} env steps, "
        f"{info['seconds']:.1f} s (compile included), learning on from here"
    )
    return filled, info


def sharded_child(args: argparse.Namespace, config: TrainConfig) -> None:
    """The subprocess with forced host devices: sharded rows as JSON on stdout."""
    trainer = make_train(config)
    info = machine_info()
    filled, fill_info = fill(trainer, args.seed)
    sharding = NamedSharding(Mesh(np.asarray(jax.devices()), ("runs",)), PartitionSpec("runs"))
    rows = [bench_batched(trainer, filled, r, args, sharding)[0] for r in args.sharded_runs]
    json.dump({"machine": info, "fill": fill_info, "rows": rows}, sys.stdout, default=str)


def run_sharded_child(args: argparse.Namespace) -> dict[str, Any]:
    """Run :func:`sharded_child` in a subprocess with ``HOST_DEVICES`` forced host devices."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = (
        f"{env.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={HOST_DEVICES}"
    ).strip()
    command = [
        sys.executable,
        os.path.abspath(__file__),
        "--sharded-child",
        "--sharded-runs",
        *map(str, args.sharded_runs),
        "--iterations",
        str(args.iterations),
        "--repeats",
        str(args.repeats),
        "--seed",
        str(args.seed),
        "--strategy",
        args.strategy,
        *(["--quick"] if args.quick else []),
    ]
    progress(f"sharded child: XLA_FLAGS={env['XLA_FLAGS']!r}")
    done = subprocess.run(command, env=env, stdout=subprocess.PIPE, text=True, check=True)
    return {"xla_flags": env["XLA_FLAGS"], **json.loads(done.stdout)}


# --------------------------------------------------------------------------- output


def cores(row: dict[str, Any]) -> str:
    """The range of "cores used" (CPU s / wall s) over a row's timed calls."""
    c = row["cores_used_per_call"]
    return f"{min(c):.2f}" if len(c) == 1 else f"{min(c):.2f}–{max(c):.2f}"


def mb(value: float | None) -> str:
    return "n/a" if value is None else f"{value:,.1f}"


def report_lines(result: dict[str, Any]) -> list[str]:
    """Markdown tables and the lines against the targets."""
    cfg, rows, s = result["config"], result["rows"], result["summary"]
    it = cfg["iterations"]
    seq = result["sequential"]
    out = [
        f"### Aggregate throughput, R runs in one program (learning active, {it} iterations "
        "per call; 1 iteration = 1 env step + 1 update per run)",
        "",
        "| runs | compile s | best s per call | env steps/s (all runs) | updates/s (all runs) "
        "| env steps/s per run | × 1 run | one after another: env steps/s "
        "| one program / one after another | cores used |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        how = "measured" if seq and r["runs"] == seq["runs"] else f"{r['runs']} × 1 run"
        out.append(
            f"| {r['runs']} | {r['compile_s']:.2f} | {r['run_s']:.3f} "
            f"| {r['env_steps_per_s']:.2f} | {r['updates_per_s']:.2f} "
            f"| {r['env_steps_per_s'] / r['runs']:.2f} | {r['speedup_vs_1_run']:.2f} "
            f"| {r['sequential_env_steps_per_s']:.2f} ({how}) | {r['vs_sequential']:.2f} "
            f"| {cores(r)} |"
        )
    out += [
        "",
        "1 run: the unbatched `jit(trainer.run)`; R > 1: the sweep's program "
        f"(`sweep_runner.call_programs`, strategy `{cfg['strategy']}`) on one device. "
        '"One after another" for R ≠ '
        + (str(seq["runs"]) if seq else "S")
        + ": R × the 1-run call time, i.e. the 1-run throughput"
        + (
            f"; for R = {seq['runs']}: the same {seq['runs']} runs (same keys) with the 1-run "
            f"program in a Python loop, best loop {seq['run_s']:.3f} s "
            f"(cores used {cores(seq)})."
            if seq
            else "."
        ),
    ]

    sharded = result["sharded"]
    if sharded and sharded.get("rows"):
        out += [
            "",
            f"### One device against sharding over {HOST_DEVICES} host devices "
            f"(strategy `{cfg['strategy']}`, subprocess)",
            "",
            f"Subprocess `XLA_FLAGS`: `{sharded['xla_flags']}`; jax.devices() there: "
            f"{', '.join(sharded['machine']['devices'])}.",
            "",
            "| runs (in the program) | devices | compile s | best s per call "
            "| env steps/s (all runs) | updates/s (all runs) | 1 device: env steps/s "
            "| sharded / 1 device | cores used |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for r in sharded["rows"]:
            one_dev = r["one_device_env_steps_per_s"]
            ratio = None if one_dev is None else r["env_steps_per_s"] / one_dev
            out.append(
                f"| {r['runs']} ({r['program_runs']}) | {r['devices']} | {r['compile_s']:.2f} "
                f"| {r['run_s']:.3f} | {r['env_steps_per_s']:.2f} | {r['updates_per_s']:.2f} "
                f"| {'n/a' if one_dev is None else f'{one_dev:.2f}'} "
                f"| {'n/a' if ratio is None else f'{ratio:.2f}'} "
                f"| {cores(r)} |"
            )
    else:
        out += ["", f"(sharding over {HOST_DEVICES} host devices: {s['sharded_note']})"]

    m = result["memory_per_run"]
    out += [
        "",
        "### Memory (MB = 10^6 bytes)",
        "",
        f"Per run: replay {m['replay_mb']:.2f} MB, online + target + Adam "
        f"{m['nets_mb']:.2f} MB ({m['params_mb']:.2f} + {m['target_mb']:.2f} + "
        f"{m['adam_mb']:.2f}), whole TrainState {m['train_state_mb']:.2f} MB.",
        "",
        "| program | runs | TrainState (all runs) | XLA arguments | outputs | aliased (donated) "
        "| temporaries | peak ≈ args + outputs − aliased + temps | peak per run |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    programs = [
        (
            "`trainer.run`" if r["runs"] == 1 else f"sweep call ({cfg['strategy']})",
            r,
            mb(r["train_state_mb"]),
        )
        for r in rows
    ]
    for name, r, state_mb in programs:
        x = r["xla_memory"] or {}
        per_run = None if r["peak_mb"] is None else r["peak_mb"] / r["runs"]
        out.append(
            f"| {name} | {r['runs']} | {state_mb} | {mb(x.get('argument_mb'))} "
            f"| {mb(x.get('output_mb'))} | {mb(x.get('alias_mb'))} | {mb(x.get('temp_mb'))} "
            f"| {mb(r['peak_mb'])} | {mb(per_run)} |"
        )
    mem = result["machine_memory"]
    out += [
        "",
        f"Machine memory (/proc/meminfo): total {mem['mem_total_gb']:.1f} GB, available "
        f"{mem['mem_available_gb']:.1f} GB at start. Peak RSS of this process: "
        f"{result['max_rss_mb']:,.0f} MB.",
        "",
        "### Against the targets (issue 6)",
        "",
    ]
    if s["batched_ratio"] is not None:
        out.append(
            f"- {seq['runs']} runs in one program: {s['batched_env_steps_per_s']:.2f} env steps/s "
            f"against {seq['env_steps_per_s']:.2f} for the same runs one after another: "
            f"**{s['batched_ratio']:.2f}×** (target: >= {TARGET_BATCHED_RATIO:g}× on the "
            f"2-core CPU; {verdict(s['batched_ratio'] >= TARGET_BATCHED_RATIO)})"
        )
    if s["run_peak_gb"] is not None:
        fits = "fits" if s["run_peak_gb"] <= SWEEP_GB else "does NOT fit"
        out.append(
            f"- {SWEEP_RUNS}-run sweep call (`{cfg['strategy']}`) of the "
            f"{'QUICK config' if cfg['quick'] else 'paper preset'}: XLA peak "
            f"{s['run_peak_gb']:.2f} GB: {fits} in {SWEEP_GB:g} GB (this machine: "
            f"{mem['mem_total_gb']:.1f} GB total)"
        )
    if s["gpu_speedup"] is not None:
        out.append(
            f"- {SWEEP_RUNS} runs in one program against 1 run on {result['backend']}: "
            f"**{s['gpu_speedup']:.2f}×** (target: >= {TARGET_GPU_SPEEDUP:g}×; "
            f"{verdict(s['gpu_speedup'] >= TARGET_GPU_SPEEDUP)})"
        )
    else:
        out.append(
            f"- GPU target ({SWEEP_RUNS} runs >= {TARGET_GPU_SPEEDUP:g}× one run): not measured "
            f"(backend {result['backend']}"
            + ("" if SWEEP_RUNS in cfg["runs"] else f", {SWEEP_RUNS} not in --runs")
            + ")"
        )
    return out


# --------------------------------------------------------------------------- main


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = base_parser("sweep_throughput", __doc__)
    parser.add_argument(
        "--runs",
        type=int,
        nargs="+",
        default=[1, 4, 16, 64],
        metavar="R",
        help="run counts, one program each; 1 is always added (default: 1 4 16 64)",
    )
    parser.add_argument(
        "--iterations",
        type=int,
        metavar="I",
        help="trainer.run iterations per timed call (default 20; 5 with --quick)",
    )
    parser.add_argument(
        "--sequential-runs",
        type=int,
        default=16,
        metavar="S",
        help="runs timed one after another with the 1-run program; 0: none (default 16)",
    )
    parser.add_argument(
        "--sharded-runs",
        type=int,
        nargs="*",
        metavar="R",
        help=f"run counts sharded over {HOST_DEVICES} host devices in a subprocess, CPU only "
        "(default: 4 16; none with --quick; give no value for none)",
    )
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed (default 0)")
    parser.add_argument(
        "--quick", action="store_true", help="tiny network and sizes: a smoke check only"
    )
    parser.add_argument(
        "--strategy",
        choices=("vmap", "map"),
        default=None,
        help="how a device trains its runs (drqn_jax.experiments.sweep_runner.STRATEGIES; "
        "default: what the sweep chooses here, map on CPU, vmap elsewhere)",
    )
    parser.add_argument("--sharded-child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.iterations is None:
        args.iterations = 5 if args.quick else 20
    if args.quick:
        args.repeats = 1
    if args.sharded_runs is None:
        args.sharded_runs = [] if args.quick else [4, 16]
    args.runs = sorted({1, *args.runs})
    if args.strategy is None:
        args.strategy = resolve_strategy("auto", jax.devices())
    if min(args.iterations, args.repeats, *args.runs, *args.sharded_runs, 1) < 1:
        parser.error("--runs, --iterations, --repeats, --sharded-runs must be >= 1")
    if args.sequential_runs < 0:
        parser.error("--sequential-runs must be >= 0")
    return args


def main(argv: Sequence[str] | None = None) -> dict[str, Any] | None:
    args = parse_args(argv)
    config = QUICK_CONFIG if args.quick else TrainConfig()
    if args.sharded_child:
        sharded_child(args, config)
        return None
    machine_memory = meminfo()
    backend = jax.default_backend()
    trainer = make_train(config)
    net = trainer.network.config
    wall_start = time.perf_counter()

    title = "QUICK SMOKE CHECK (tiny network; not a measurement)" if args.quick else "paper preset"
    setup = (
        f"TrainConfig: num_envs={config.num_envs}, replay_episodes={config.replay_episodes}, "
        f"batch_size={config.batch_size}, window={config.window}, "
        f"updates_per_step={config.updates_per_step}, env max_steps="
        f"{trainer.env.static.max_steps}, network {net.kind} (conv {net.conv}, recurrent "
        f"{net.recurrent}, hidden {net.hidden}). One run's replay filled (learning off) until "
        f"learning_starts = {int(config.hyperparams.learning_starts)} episodes, then learning "
        "on; the R runs are R copies of it with different PRNG keys. Median of "
        f"{args.repeats} timed calls after 1 warm-up, each continuing from the last; compile s "
        "= lower + XLA compile."
    )
    print(setup, file=sys.stderr, flush=True)

    filled, fill_info = fill(trainer, args.seed)
    one, one_run_program = bench_batched(trainer, filled, 1, args)  # args.runs[0] is 1
    rows = [one] + [bench_batched(trainer, filled, r, args)[0] for r in args.runs[1:]]
    sequential = (
        bench_sequential(trainer, filled, args.sequential_runs, args, one_run_program)
        if args.sequential_runs
        else None
    )
    for r in rows:
        measured = sequential is not None and r["runs"] == sequential["runs"]
        r["sequential_env_steps_per_s"] = (
            sequential["env_steps_per_s"] if measured else one["env_steps_per_s"]
        )
        r["sequential_measured"] = measured
        r["vs_sequential"] = r["env_steps_per_s"] / r["sequential_env_steps_per_s"]
        r["speedup_vs_1_run"] = r["env_steps_per_s"] / one["env_steps_per_s"]

    if backend != "cpu":
        sharded: dict[str, Any] = {}
        sharded_note = f"skipped: backend {backend}, host devices only make sense on CPU"
    elif args.sharded_runs:
        sharded = run_sharded_child(args)
        sharded_note = "measured"
        if sharded["fill"]["env_steps"] != fill_info["env_steps"]:
            raise RuntimeError("the sharded child filled its replay differently")
        by_runs = {r["runs"]: r["env_steps_per_s"] for r in rows}
        for r in sharded["rows"]:
            r["one_device_env_steps_per_s"] = by_runs.get(r["runs"])
    else:
        sharded, sharded_note = {}, "not asked for (--sharded-runs)"

    by_runs = {r["runs"]: r for r in rows}
    seq_row = by_runs.get(args.sequential_runs) if sequential else None
    run_64 = by_runs.get(SWEEP_RUNS)
    summary = {
        "batched_env_steps_per_s": seq_row["env_steps_per_s"] if seq_row else None,
        "batched_ratio": seq_row["vs_sequential"] if seq_row else None,
        "meets_batched_target": (
            seq_row["vs_sequential"] >= TARGET_BATCHED_RATIO if seq_row else None
        ),
        "run_peak_gb": run_64["peak_mb"] * MB / GB if run_64 and run_64["peak_mb"] else None,
        "gpu_speedup": (
            run_64["speedup_vs_1_run"] if backend != "cpu" and run_64 is not None else None
        ),
        "sharded_note": sharded_note,
    }
    result = {
        "machine_memory": machine_memory,
        "backend": backend,
        "config": {
            "quick": args.quick,
            "runs": args.runs,
            "iterations": args.iterations,
            "strategy": args.strategy,
            "repeats": args.repeats,
            "sequential_runs": args.sequential_runs,
            "sharded_runs": args.sharded_runs,
            "seed": args.seed,
            "train_config": {
                k: v for k, v in dataclasses.asdict(config).items() if k != "hyperparams"
            },
        },
        "fill": fill_info,
        "memory_per_run": {
            "replay_mb": replay_bytes(filled.replay) / MB,
            "params_mb": tree_bytes(filled.online) / MB,
            "target_mb": tree_bytes(filled.target) / MB,
            "adam_mb": tree_bytes(filled.opt_state) / MB,
            "nets_mb": tree_bytes((filled.online, filled.target, filled.opt_state)) / MB,
            "train_state_mb": tree_bytes(filled) / MB,
        },
        "rows": rows,
        "sequential": sequential,
        "sharded": sharded,
        "summary": summary,
        "wall_s": time.perf_counter() - wall_start,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / MB,
        "loadavg_1min_at_end": os.getloadavg()[0],
    }

    lines = [
        setup,
        "",
        *report_lines(result),
        "",
        f"(benchmark wall time {result['wall_s']:.0f} s; load average (1 min) at end "
        f"{result['loadavg_1min_at_end']:.2f})",
    ]
    title = "DRQN sweep throughput, " + title
    return report("sweep_throughput", title, result, lines, args.out, argv)


if __name__ == "__main__":
    main()
