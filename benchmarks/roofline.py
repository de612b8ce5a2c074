"""The machine's limits, and where the env step and the gradient update stand against them.

Usage::

    python -m benchmarks.roofline [--repeats N] [--mb MB] [--env-batch N] [--steps T]
        [--updates K] [--compare-fma] [--out DIR] [--quick]

1. **This machine, as we run it** (``import drqn_jax`` caps XLA:CPU at AVX, no
   FMA; the mode is in the result): memory bandwidth from jitted programs on a
   ``--mb`` MB float32 array whose buffer is donated, so every call reuses
   memory already mapped: *read + write* = ``x + 1`` in place (2 × size bytes
   per call), *write* = a fill of the array with a new value (size bytes; the
   unused argument is kept, ``keep_unused=True``, so XLA writes into it); for
   comparison the same fill into a *fresh* output buffer (what a program
   without donation pays: first-touch page faults) and NumPy ``np.copyto``
   between two arrays (2 × size bytes, one thread). Matmul rate: jitted float32
   ``a @ b`` at 1024³ and 2048³ and the skinny (256, 2048) @ (2048, 1024),
   GFLOP/s = 2·m·n·k / time. ``--compare-fma`` repeats this part in a
   subprocess with ``DRQN_JAX_ALLOW_FMA=1`` (FMA allowed) and reports both.
2. **Per env step**: XLA's ``cost_analysis()`` of the compiled env rollout of
   ``benchmarks/env_throughput.py`` (``lax.scan`` of T vmapped ``env.step`` on
   N envs): "flops" and "bytes accessed". XLA counts a ``while`` (scan) body
   once, whatever its trip count (checked on a small scan at run time), so
   the figures are divided by N, not N·T. The must-write bytes: the float32
   (45, 30, 4) observation, 21,600 B. Measured: env steps/s of that rollout
   (median of ``--repeats`` calls after a warm-up, carry donated).
   **Per gradient update** (minibatch 32 windows × 8 steps, the paper
   network, ``TrainConfig()``): the machinery of
   ``benchmarks/train_throughput.py``: the replay filled by ``fill_replay``
   (learning off) up to ``learning_starts`` episodes, FLOPs counted from the
   update's jaxpr (``count_flops``: 2·MACs of every matmul/conv, scan bodies
   × length), XLA's ``cost_analysis()`` of the compiled update (flops and
   bytes accessed; the LSTM unroll counted once, so an undercount), the
   analytic count (``analytic_update_flops``), and updates/s from K updates
   in one jitted ``lax.scan`` (``make_updates``); XLA's figures are those of
   that program (its body, one update, counted once).
3. **Roofline fractions**: achieved rate ÷ machine limit. Env: observation
   bytes written per second ÷ write bandwidth, XLA bytes accessed per second
   ÷ read + write bandwidth, XLA flops per second ÷ matmul rate. Update:
   counted GFLOP/s ÷ matmul GFLOP/s (large square, skinny), XLA bytes per
   second ÷ read + write bandwidth, and the bound time per update max(FLOPs ÷
   best matmul rate, bytes ÷ read + write bandwidth) ÷ the measured time.
   Then the issue's targets: env ≥ min(1,000,000 steps/s, 70 % of the
   observation-write bound = write bandwidth ÷ 21,600 B), training ≥ 40
   updates/s.

``--quick``: a 16 MB array, matmuls at 256³ and (64, 256) @ (256, 128), env N
= 64 and T = 10, the ``smoke`` training config on a synthetic replay (``synthetic_replay``:
every slot complete, its records tiled from the env rollout's final states, so
neither ``trainer.init`` nor ``trainer.run`` is compiled; the update's cost
does not depend on the replay's contents), 3 updates per call, 2 repeats: a
smoke check of the script, not a measurement.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import drqn_jax
from benchmarks.env_throughput import ENV_ID, QUICK_ENVS, QUICK_STEPS, grid_bytes, time_rollout
from benchmarks.harness import base_parser, compile_timed, markdown_table, report, time_calls
from benchmarks.train_throughput import (
    analytic_update_flops,
    count_flops,
    fill_replay,
    make_updates,
    memory_of,
)
from drqn_jax.config import load_config
from drqn_jax.determinism import fma_disabled
from drqn_jax.env.grid import GridInputs
from drqn_jax.learners import TrainConfig, Trainer, make_train
from drqn_jax.learners.dqn.replay import EpisodeReplay, init_replay
from drqn_jax.learners.optim import adam

__all__ = [
    "TARGET_ENV_FRACTION",
    "TARGET_ENV_STEPS_PER_S",
    "TARGET_UPDATES_PER_S",
    "cost_of",
    "main",
    "measure_bandwidth",
    "measure_env",
    "measure_machine",
    "measure_matmul",
    "measure_update",
]

# The targets.
TARGET_ENV_STEPS_PER_S = 1_000_000
TARGET_ENV_FRACTION = 0.7  # ... or 70 % of the observation-write bound, whichever is lower
TARGET_UPDATES_PER_S = 40.0

MATMULS = {"square 1024³": (1024, 1024, 1024), "square 2048³": (2048, 2048, 2048)}
SKINNY = ("skinny (256, 2048) @ (2048, 1024)", (256, 2048, 1024))
QUICK_MATMULS = {"square 256³": (256, 256, 256)}
QUICK_SKINNY = ("skinny (64, 256) @ (256, 128)", (64, 256, 128))
GB = 1e9


# --------------------------------------------------------------------------- 1. the machine


def measure_bandwidth(nbytes: int, repeats: int) -> dict[str, Any]:
    """GB/s (10^9 B/s) of in-place read + write, fill, fill into fresh memory, NumPy copy."""
    n = nbytes // 4
    nbytes = 4 * n
    x = jnp.zeros((n,), jnp.float32)

    increment = jax.jit(lambda x: x + 1.0, donate_argnums=0)
    x, rw = time_calls(increment, x, repeats)

    def fill(carry: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        x, c = carry
        return jnp.full(x.shape, c, x.dtype), c + 1.0

    fill_donated = jax.jit(fill, donate_argnums=0, keep_unused=True)
    (x, _), w = time_calls(fill_donated, (x, jnp.float32(0.0)), repeats)
    del x
    # Without donation every call writes into newly mapped pages.
    # (The carry holds the last array, so each call waits for its fill.)
    fill_fresh = jax.jit(lambda c: (jnp.full((n,), c, jnp.float32), c + 1.0))
    _, w_fresh = time_calls(lambda xc: fill_fresh(xc[1]), (None, jnp.float32(0.0)), repeats)

    src = np.ones(n, np.float32)
    dst = np.empty_like(src)
    np_s = time_calls(lambda _: np.copyto(dst, src), None, repeats)[1]["run_s"]
    return {
        "array_bytes": nbytes,
        "read_write_gb_per_s": 2 * nbytes / rw["run_s"] / GB,
        "write_gb_per_s": nbytes / w["run_s"] / GB,
        "write_fresh_gb_per_s": nbytes / w_fresh["run_s"] / GB,
        "numpy_copy_gb_per_s": 2 * nbytes / np_s / GB,
        "read_write_run_times_s": rw["run_times_s"],
        "write_run_times_s": w["run_times_s"],
        "write_fresh_run_times_s": w_fresh["run_times_s"],
        "numpy_copy_s": np_s,
    }


def measure_matmul(shapes: dict[str, tuple[int, int, int]], repeats: int) -> dict[str, Any]:
    """GFLOP/s of jitted float32 ``a @ b`` for each ``name: (m, k, n)``."""
    out = {}
    for i, (name, (m, k, n)) in enumerate(shapes.items()):
        ka, kb = jax.random.split(jax.random.key(i))
        a = jax.random.normal(ka, (m, k), jnp.float32)
        b = jax.random.normal(kb, (k, n), jnp.float32)
        matmul = jax.jit(jnp.matmul)
        _, t = time_calls(lambda _, a=a, b=b, f=matmul: f(a, b), None, repeats)
        flops = 2.0 * m * n * k
        out[name] = {
            "m": m,
            "k": k,
            "n": n,
            "flops": flops,
            "run_s": t["run_s"],
            "run_times_s": t["run_times_s"],
            "gflops_per_s": flops / t["run_s"] / GB,
        }
    return out


def measure_machine(quick: bool, nbytes: int, repeats: int) -> dict[str, Any]:
    """Bandwidths, matmul rates and the code generation mode they were measured in."""
    squares = QUICK_MATMULS if quick else MATMULS
    skinny_name, skinny = QUICK_SKINNY if quick else SKINNY
    matmul = measure_matmul({**squares, skinny_name: skinny}, repeats)
    best_square = max(squares, key=lambda s: matmul[s]["gflops_per_s"])
    return {
        "fma_disabled": fma_disabled(),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "bandwidth": measure_bandwidth(nbytes, repeats),
        "matmul": matmul,
        "square_name": best_square,
        "square_gflops_per_s": matmul[best_square]["gflops_per_s"],
        "skinny_name": skinny_name,
        "skinny_gflops_per_s": matmul[skinny_name]["gflops_per_s"],
    }


def machine_with_fma(args: argparse.Namespace) -> dict[str, Any] | None:
    """Part 1 again in a subprocess with FMA allowed (``DRQN_JAX_ALLOW_FMA=1``)."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "benchmarks.roofline", "--machine-only", "--out", tmp]
        cmd += ["--repeats", str(args.repeats), "--mb", str(args.mb)]
        cmd += ["--quick"] if args.quick else []
        env = dict(os.environ, DRQN_JAX_ALLOW_FMA="1")
        env["XLA_FLAGS"] = env.get("XLA_FLAGS", "").replace("--xla_cpu_max_isa=AVX", "").strip()
        root = Path(__file__).resolve().parents[1]
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(root), env.get("PYTHONPATH")]))
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=root)
        if proc.returncode != 0:
            print(f"--compare-fma failed:\n{proc.stderr[-2000:]}", file=sys.stderr)
            return None
        return json.loads((Path(tmp) / "roofline.json").read_text())["machine_limits"]


# --------------------------------------------------------------------------- 2. per step / update


def cost_of(compiled: jax.stages.Compiled) -> dict[str, float]:
    """XLA's ``cost_analysis()`` totals: flops, bytes accessed, transcendentals (a dict in
    this JAX; a list of dicts, one per computation, in older ones: the first is taken)."""
    try:
        ca = compiled.cost_analysis()
    except Exception:  # not every backend implements it
        return {}
    if isinstance(ca, list | tuple):
        ca = ca[0] if ca else {}
    keys = ("flops", "bytes accessed", "transcendentals")
    return {k: float(ca[k]) for k in keys if ca and k in ca}


def cost_keys(compiled: jax.stages.Compiled) -> list[str]:
    """The distinct key names of ``cost_analysis()``, operand and output indices as ``N``."""
    ca = compiled.cost_analysis()
    if isinstance(ca, list | tuple):
        ca = ca[0] if ca else {}
    return sorted({re.sub(r"\d+", "N", k) for k in ca})


@functools.cache
def while_body_counted_once() -> bool:
    """Whether ``cost_analysis`` counts a scan body once whatever its length (small check)."""

    def scan(length: int) -> float:
        def f(x: jax.Array) -> jax.Array:
            return jax.lax.scan(lambda c, _: (jnp.sin(c) * 2.0 + 1.0, None), x, length=length)[0]

        x = jnp.zeros((256,), jnp.float32)
        return cost_of(jax.jit(f).lower(x).compile()).get("flops", math.nan)

    return scan(4) == scan(8)


def measure_env(
    env: drqn_jax.UrbanPedestrians,
    params: drqn_jax.EnvParams,
    num_envs: int,
    num_steps: int,
    repeats: int,
) -> tuple[dict[str, Any], GridInputs]:
    """Bytes and FLOPs per env step (XLA) and env steps/s of env_throughput's rollout;
    and the rollout's final states as grid records (N, …)."""
    t, carry, compiled = time_rollout(env, params, num_envs, num_steps, repeats, jax.random.key(0))
    cost = cost_of(compiled)
    once = while_body_counted_once()
    steps_in_cost = num_envs if once else num_envs * num_steps
    _, state, _ = carry
    records = GridInputs.of(state.ego, state.pedestrians)
    steps_per_s = t["env_steps_per_s"]
    row = {
        **t,
        "cost_analysis_keys": cost_keys(compiled),
        "cost_analysis": cost,
        "while_body_counted_once": once,
        "env_steps_in_cost": steps_in_cost,
        "flops_per_step": cost.get("flops", math.nan) / steps_in_cost,
        "bytes_accessed_per_step": cost.get("bytes accessed", math.nan) / steps_in_cost,
        "obs_bytes_per_step": grid_bytes(env),
        "obs_gb_per_s": steps_per_s * grid_bytes(env) / GB,
    }
    return row, records


def synthetic_replay(
    trainer: Trainer, records: GridInputs, seed: int = 0
) -> tuple[tuple, EpisodeReplay]:
    """A learner and a replay with every slot complete and full, its records tiled from
    ``records`` (N states of the env, e.g. after a rollout), built without compiling
    ``trainer.init`` or ``trainer.run``. The update's cost does not depend on what the
    replay or the weights hold: sampling, rasterisation, the network and Adam have no
    data-dependent branch."""
    cfg, static = trainer.config, trainer.env.static
    hp = cfg.hyperparams
    # Weights of the network's shapes drawn by NumPy: compiling the initialiser costs
    # seconds here, and the update's cost does not depend on the values either.
    rng = np.random.default_rng(seed)
    shapes = jax.eval_shape(trainer.network.init, jax.random.key(seed))
    online = jax.tree.map(
        lambda s: jnp.asarray(rng.uniform(-0.1, 0.1, s.shape).astype(s.dtype)), shapes
    )
    opt_state = adam(hp.learning_rate, hp.adam_b1, hp.adam_b2, hp.adam_eps).init(online)
    learner = (online, online, opt_state, jnp.zeros((), jnp.int32))
    replay = init_replay(cfg.replay_episodes, static.max_steps, cfg.num_envs, trainer.task.record)
    count = replay.records.s.size  # M × (L + 1) records
    index = jnp.arange(count) % records.s.shape[0]
    tiled = jax.tree.map(lambda b, x: x[index].reshape(b.shape), replay.records, records)
    replay = replay.replace(
        records=tiled,
        complete=jnp.ones_like(replay.complete),
        length=jnp.full_like(replay.length, replay.max_length),
    )
    return learner, replay


def measure_update(
    config: TrainConfig, num_updates: int, repeats: int, records: GridInputs | None = None
) -> dict[str, Any]:
    """FLOPs, bytes and updates/s of one gradient update (train_throughput's machinery).

    The replay is filled by ``fill_replay`` (``learning_starts`` episodes acted with
    learning off), or, given env ``records``, by :func:`synthetic_replay`."""
    trainer = make_train(config)
    t0 = time.perf_counter()
    if records is not None:
        learner, replay = synthetic_replay(trainer, records)
        fill: dict[str, Any] = {"recorded": 0}
    else:
        fill_run = jax.jit(trainer.run, static_argnums=1, donate_argnums=0)
        episodes = int(config.hyperparams.learning_starts)
        state, fill = fill_replay(trainer, jax.random.key(0), episodes, fill_run)
        learner = (state.online, state.target, state.opt_state, state.grad_steps)
        replay = state.replay
    fill_s = time.perf_counter() - t0

    update = trainer.gradient_update
    key = jax.random.key(1)
    statics = (replay, config.hyperparams, trainer.env_params)
    counted = count_flops(jax.make_jaxpr(update)(learner, key, *statics).jaxpr)

    updates = jax.jit(make_updates(update, num_updates))
    compiled, lower_s, xla_s = compile_timed(updates, learner, key, *statics)
    # XLA counts the scan body, one update, once (checked): no second program to compile.
    once = while_body_counted_once()
    cost = {k: v / (1 if once else num_updates) for k, v in cost_of(compiled).items()}
    before = int(learner[3])
    learner, t = time_calls(lambda c: compiled(c, key, *statics)[0], learner, repeats)
    done = int(learner[3]) - before
    if done != num_updates * (repeats + 1):
        raise RuntimeError(f"{done} gradient steps, expected {num_updates * (repeats + 1)}")
    updates_per_s = num_updates / t["run_s"]
    return {
        "batch_size": config.batch_size,
        "window": config.window,
        "network": {
            "kind": config.network.kind,
            "conv": config.network.conv,
            "recurrent": config.network.recurrent,
            "hidden": config.network.hidden,
        },
        "fill_s": fill_s,
        "fill_episodes": fill["recorded"],
        "synthetic_replay": records is not None,
        "updates_per_call": num_updates,
        "compile_s": lower_s + xla_s,
        **t,
        "updates_per_s": updates_per_s,
        "counted_flops": counted["matmul"],
        "counted_elementwise": counted["elementwise"],
        "analytic_flops": analytic_update_flops(config, trainer.network.config)["total_flops"],
        "cost_analysis": cost,
        "xla_flops": cost.get("flops", math.nan),
        "bytes_accessed": cost.get("bytes accessed", math.nan),
        "xla_memory_of_k_updates": memory_of(compiled),
        "gflops_per_s": updates_per_s * counted["matmul"] / GB,
    }


# --------------------------------------------------------------------------- 3. fractions


def _fmt_bytes(b: float) -> str:
    return f"{b / 1e3:,.1f} kB" if b < 1e6 else f"{b / 1e6:,.2f} MB"


def _fmt_flops(f: float) -> str:
    return f"{f / 1e3:,.1f} kFLOP" if f < 1e6 else f"{f / 1e6:,.2f} MFLOP"


def _row(figure: str, per: str, achieved: float, limit: float, unit: str) -> dict[str, Any]:
    return {
        "figure": figure,
        "per": per,
        "achieved": achieved,
        "limit": limit,
        "unit": unit,
        "fraction": achieved / limit,
        "achieved_text": f"{achieved:,.3g} {unit}",
        "limit_text": f"{limit:,.3g} {unit}",
        "fraction_text": f"{100 * achieved / limit:.1f}%",
    }


def fractions(m: dict[str, Any], e: dict[str, Any], u: dict[str, Any]) -> list[dict[str, Any]]:
    """The roofline table: every figure as achieved rate against a machine limit."""
    bw, steps, ups = m["bandwidth"], e["env_steps_per_s"], u["updates_per_s"]
    square, skinny = m["square_gflops_per_s"], m["skinny_gflops_per_s"]
    best = max(square, skinny)
    flops, nbytes = u["counted_flops"], u["bytes_accessed"]
    bound_s = max(flops / (best * GB), nbytes / (bw["read_write_gb_per_s"] * GB))
    env = f"env step (N = {e['batch_size']})"
    return [
        _row(
            f"{env}: observation written",
            f"{e['obs_bytes_per_step']:,} B",
            steps * e["obs_bytes_per_step"] / GB,
            bw["write_gb_per_s"],
            "GB/s",
        ),
        _row(
            f"{env}: bytes accessed (XLA)",
            _fmt_bytes(e["bytes_accessed_per_step"]),
            steps * e["bytes_accessed_per_step"] / GB,
            bw["read_write_gb_per_s"],
            "GB/s",
        ),
        _row(
            f"{env}: flops (XLA) vs matmul rate",
            _fmt_flops(e["flops_per_step"]),
            steps * e["flops_per_step"] / GB,
            best,
            "GFLOP/s",
        ),
        _row(
            f"update: counted FLOPs vs {m['square_name']}",
            _fmt_flops(flops),
            ups * flops / GB,
            square,
            "GFLOP/s",
        ),
        _row(
            f"update: counted FLOPs vs {m['skinny_name']}",
            _fmt_flops(flops),
            ups * flops / GB,
            skinny,
            "GFLOP/s",
        ),
        _row(
            "update: bytes accessed (XLA, LSTM unroll once)",
            _fmt_bytes(nbytes),
            ups * nbytes / GB,
            bw["read_write_gb_per_s"],
            "GB/s",
        ),
        _row(
            "update: bound time ÷ measured time",
            f"bound {1e3 * bound_s:.3g} ms",
            ups,
            1.0 / bound_s,
            "updates/s",
        ),
    ]


def targets(m: dict[str, Any], e: dict[str, Any], u: dict[str, Any]) -> dict[str, Any]:
    """The issue's targets from the measured limits (nothing hard-coded but the rules)."""
    obs_bound = m["bandwidth"]["write_gb_per_s"] * GB / e["obs_bytes_per_step"]
    env_target = min(TARGET_ENV_STEPS_PER_S, TARGET_ENV_FRACTION * obs_bound)
    return {
        "obs_write_bound_steps_per_s": obs_bound,
        "env_target_steps_per_s": env_target,
        "env_steps_per_s": e["env_steps_per_s"],
        "env_met": e["env_steps_per_s"] >= env_target,
        "updates_target_per_s": TARGET_UPDATES_PER_S,
        "updates_per_s": u["updates_per_s"],
        "updates_met": u["updates_per_s"] >= TARGET_UPDATES_PER_S,
    }


COLUMNS = {
    "figure": "figure",
    "per": "per step/update",
    "achieved_text": "achieved rate",
    "limit_text": "machine limit",
    "fraction_text": "fraction of the limit",
}


def machine_lines(m: dict[str, Any], fma: dict[str, Any] | None) -> list[str]:
    """The machine table: each limit as measured, and with FMA allowed when given."""
    bw = m["bandwidth"]
    mode = "AVX, no FMA" if m["fma_disabled"] else "FMA allowed"
    rows = [
        {
            "what": f"read + write (`x + 1` in place, {bw['array_bytes'] / 1e6:.0f} MB)",
            "value": f"{bw['read_write_gb_per_s']:.3g} GB/s",
            "key": ("bandwidth", "read_write"),
        },
        {
            "what": "write (fill of a donated array)",
            "value": f"{bw['write_gb_per_s']:.3g} GB/s",
            "key": ("bandwidth", "write"),
        },
        {
            "what": "write into fresh memory (no donation: page faults)",
            "value": f"{bw['write_fresh_gb_per_s']:.3g} GB/s",
            "key": ("bandwidth", "write_fresh"),
        },
        {
            "what": "NumPy `np.copyto` (read + write, one thread)",
            "value": f"{bw['numpy_copy_gb_per_s']:.3g} GB/s",
            "key": ("bandwidth", "numpy_copy"),
        },
    ]
    for name, mm in m["matmul"].items():
        rows.append(
            {
                "what": f"matmul {name}",
                "value": f"{mm['gflops_per_s']:.3g} GFLOP/s",
                "key": ("matmul", name),
            }
        )
    columns = {"what": "limit", "value": f"measured ({mode})"}
    if fma is not None:
        for r in rows:
            kind, name = r["key"]
            if kind == "bandwidth":
                r["fma"] = f"{fma['bandwidth'][f'{name}_gb_per_s']:.3g} GB/s"
            else:
                r["fma"] = f"{fma['matmul'][name]['gflops_per_s']:.3g} GFLOP/s"
        columns["fma"] = "FMA allowed (subprocess)" if not fma["fma_disabled"] else "subprocess"
    return markdown_table(rows, columns)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = base_parser("roofline", __doc__)
    parser.add_argument("--mb", type=int, default=256, help="array size in MB (default 256)")
    parser.add_argument(
        "--env-batch", type=int, default=4096, metavar="N", help="envs in the rollout (4096)"
    )
    parser.add_argument("--steps", type=int, default=100, metavar="T", help="rollout length (100)")
    parser.add_argument(
        "--updates", type=int, default=20, metavar="K", help="updates per timed call (20)"
    )
    parser.add_argument(
        "--compare-fma",
        action="store_true",
        help="also measure the machine with FMA allowed (a subprocess)",
    )
    parser.add_argument("--machine-only", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument(
        "--quick",
        action="store_true",
        help="16 MB, matmul 256³, env N = 64 and T = 10, smoke training config, 2 repeats",
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.mb, args.updates, args.repeats = 16, 3, 2
        args.env_batch, args.steps = QUICK_ENVS, QUICK_STEPS
    if min(args.mb, args.env_batch, args.steps, args.updates, args.repeats) < 1:
        parser.error("--mb, --env-batch, --steps, --updates, --repeats must be >= 1")
    return args


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Run the benchmark; print (and with ``--out`` write) the report; return the result."""
    args = parse_args(argv)
    m = measure_machine(args.quick, args.mb * 10**6, args.repeats)
    print(
        f"[machine: {m['bandwidth']['read_write_gb_per_s']:.3g} GB/s read + write, "
        f"{m['bandwidth']['write_gb_per_s']:.3g} GB/s write, {m['square_name']} "
        f"{m['square_gflops_per_s']:.3g} GFLOP/s, {m['skinny_name']} "
        f"{m['skinny_gflops_per_s']:.3g} GFLOP/s]",
        file=sys.stderr,
        flush=True,
    )
    if args.machine_only:
        return report("roofline", "Machine limits", {"machine_limits": m}, [], args.out, argv)
    fma = machine_with_fma(args) if args.compare_fma else None

    env, params = drqn_jax.make(ENV_ID)
    e, records = measure_env(env, params, args.env_batch, args.steps, args.repeats)
    print(f"[env: {e['env_steps_per_s']:,.0f} env steps/s]", file=sys.stderr, flush=True)
    config = load_config("smoke").train_config() if args.quick else TrainConfig()
    u = measure_update(config, args.updates, args.repeats, records if args.quick else None)
    print(f"[update: {u['updates_per_s']:.2f} updates/s]", file=sys.stderr, flush=True)

    rows = fractions(m, e, u)
    tg = targets(m, e, u)

    def verdict(ok: bool) -> str:
        return "met" if ok else "MISSED"

    net = u["network"]
    lines = [
        "### This machine (median of "
        f"{args.repeats} calls after 1 warm-up; GB = 10^9 B; XLA_FLAGS: `{m['xla_flags']}`)",
        "",
        *machine_lines(m, fma),
        "",
        "### Where we stand",
        "",
        f"Env: `{ENV_ID}`, rollout of env_throughput.py, N = {e['batch_size']}, T = "
        f"{e['steps']}: {e['env_steps_per_s']:,.0f} env steps/s; XLA cost_analysis of the "
        f"compiled rollout ÷ {e['env_steps_in_cost']:,} env-steps (the scan body is counted "
        f"{'once' if e['while_body_counted_once'] else 'per iteration'}). Update: batch "
        f"{u['batch_size']} × {u['window']}, {net['kind']} network (conv {net['conv']}, "
        f"recurrent {net['recurrent']}, hidden {net['hidden']}): {u['updates_per_s']:.2f} "
        f"updates/s ({u['updates_per_call']} per call); FLOPs counted from the jaxpr "
        f"{u['counted_flops'] / 1e6:,.2f} M (matmul only), XLA {u['xla_flops'] / 1e6:,.2f} M, "
        f"analytic {u['analytic_flops'] / 1e6:,.2f} M."
        + (
            " QUICK: a smoke check (smoke training config), not a measurement."
            if args.quick
            else ""
        ),
        "",
        *markdown_table(rows, COLUMNS),
        "",
        "### The issue's targets",
        "",
        f"- env: {tg['env_steps_per_s']:,.0f} env steps/s at N = {e['batch_size']} against "
        f">= min({TARGET_ENV_STEPS_PER_S:,}, {100 * TARGET_ENV_FRACTION:.0f}% of the "
        f"observation-write bound {tg['obs_write_bound_steps_per_s']:,.0f}) = "
        f"{tg['env_target_steps_per_s']:,.0f}: **{verdict(tg['env_met'])}**",
        f"- training: {tg['updates_per_s']:.2f} gradient updates/s against >= "
        f"{TARGET_UPDATES_PER_S:g}: **{verdict(tg['updates_met'])}**",
    ]
    result = {
        "config": {
            "quick": args.quick,
            "repeats": args.repeats,
            "mb": args.mb,
            "env_batch": args.env_batch,
            "steps": args.steps,
            "updates": args.updates,
            "stat": "median",
        },
        "machine_limits": m,
        "machine_limits_fma": fma,
        "env": e,
        "update": u,
        "rows": rows,
        "targets": tg,
    }
    return report(
        "roofline", "Roofline: machine limits and where we stand", result, lines, args.out, argv
    )


if __name__ == "__main__":
    main()
