"""Peers: our env against highway-env, the driving RL env a user would otherwise pick.

Usage::

    python -m benchmarks.peers [--repeats 5] [--out DIR] [--quick] [--num-envs 4096]
        [--steps 200] [--highway-steps 100] [--no-highway]

Timed side by side in one process, random actions, full observation every step:

* **ours**: ``UrbanPedestrians-v0``, ``--num-envs`` envs in one jitted
  ``lax.scan`` of ``--steps`` vmapped steps (:func:`benchmarks.env_throughput.time_rollout`);
  a step simulates 0.1 s;
* **highway-env** ``intersection-v0`` (``pip install -e ".[bench]"``) with an
  ``OccupancyGrid`` shaped like ours (45 m ahead × 30 m across, 1 m cells, four
  per-vehicle features); one ``env.step`` is one policy decision of
  ``1 / policy_frequency`` s. Unavailable (with the reason) when it cannot be imported.

Each call: one warm-up, then the median of ``--repeats`` (``harness.time_calls``).
Reported: steps/s, simulated seconds per wall second, and ours over it per step and
per simulated second.
"""

import importlib
import importlib.metadata
import math
import re
import statistics
import sys
import time
import warnings
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

import drqn_jax
from benchmarks import harness
from benchmarks.env_throughput import QUICK_ENVS, QUICK_STEPS, time_rollout

ENV_ID = "UrbanPedestrians-v0"
HIGHWAY_ENV_ID = "intersection-v0"
INSTALL_HINT = 'pip install -e ".[bench]"'
TARGET_VS_HIGHWAY = 10_000.0

FULL = {"num_envs": 4096, "steps": 200, "highway_steps": 100, "repeats": 5}
QUICK = {"num_envs": QUICK_ENVS, "steps": QUICK_STEPS, "highway_steps": 20, "repeats": 2}

# An OccupancyGrid like ours: rows forward from -5 m to 40 m, columns across from -15 m
# to 15 m, 1 m cells, in the ego's axes; four per-agent channels (ours: presence,
# heading, speed, semantic class of the pedestrian), normalised to [-1, 1].
HIGHWAY_OBSERVATION: dict[str, Any] = {
    "type": "OccupancyGrid",
    "features": ["presence", "vx", "vy", "heading"],
    "features_range": {"vx": [-20, 20], "vy": [-20, 20], "heading": [-math.pi, math.pi]},
    "grid_size": [[-5, 40], [-15, 15]],
    "grid_step": [1, 1],
    "align_to_vehicle_axes": True,
}


def _mean(values: Sequence[float]) -> float:
    return statistics.fmean(values) if values else float("nan")


def bench_ours(num_envs: int, num_steps: int, repeats: int, seed: int) -> dict[str, Any]:
    """Time ``num_steps`` vmapped steps of ``num_envs`` envs per call; the row of ours."""
    env, params = drqn_jax.make(ENV_ID)
    timing, carry, _ = time_rollout(env, params, num_envs, num_steps, repeats, jax.random.key(seed))
    grid_finite = bool(np.isfinite(np.asarray(carry[0].grid)).all())
    del carry
    dt = float(params.dt)
    steps_per_s = timing["env_steps_per_s"]
    return {
        "available": True,
        "implementation": f"ours: {ENV_ID}, JAX, {num_envs} envs at once",
        "step": f"one env step ({dt:g} s)",
        "num_envs": num_envs,
        "steps_per_call": num_steps,
        "seconds_per_step": dt,
        **timing,
        "steps_per_s": steps_per_s,
        "sim_s_per_wall_s": steps_per_s * dt,
        "cores_used": _mean(timing["cores_used_per_call"]),
        "grid_shape": list(env.static.grid_shape),
        "grid_finite": grid_finite,
    }


def highway_unavailable(reason: str) -> dict[str, Any]:
    """The highway-env entry when it is not measured, with ``reason``."""
    return {
        "available": False,
        "implementation": f"highway-env {HIGHWAY_ENV_ID}",
        "reason": reason,
    }


def import_highway() -> tuple[Any, Any, str] | str:
    """``(gymnasium, highway_env, version)``, or the reason highway-env cannot be used."""
    try:
        gym = importlib.import_module("gymnasium")
        highway_env = importlib.import_module("highway_env")
    except Exception as exc:  # ImportError, or a broken install failing on import
        return f"cannot import highway_env ({type(exc).__name__}: {exc}); {INSTALL_HINT}"
    try:
        version = importlib.metadata.version("highway-env")
    except importlib.metadata.PackageNotFoundError:
        version = getattr(highway_env, "__version__", "unknown")
    return gym, highway_env, version


def bench_highway(num_steps: int, repeats: int, seed: int) -> dict[str, Any]:
    """Time ``num_steps`` decision steps of highway-env per call; its row (or unavailable)."""
    imported = import_highway()
    if isinstance(imported, str):
        return highway_unavailable(imported)
    gym, _, version = imported

    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make(HIGHWAY_ENV_ID, config={"observation": dict(HIGHWAY_OBSERVATION)})
        obs, _ = env.reset(seed=seed)
    setup_s = time.perf_counter() - t0
    # gymnasium colours its warnings with ANSI escapes; keep the text.
    messages = sorted({re.sub(r"\x1b\[[0-9;]*m", "", str(w.message)) for w in caught})
    for message in messages:
        print(f"[highway-env warning: {message}]", file=sys.stderr)
    env.action_space.seed(seed)
    config = env.unwrapped.config
    sim_hz, policy_hz = config["simulation_frequency"], config["policy_frequency"]
    episodes = [0]

    def call(obs: Any) -> Any:
        for _ in range(num_steps):
            obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                obs, _ = env.reset()
                episodes[0] += 1
        return obs

    obs, timing = harness.time_calls(call, obs, repeats)
    env.close()
    seconds_per_step = 1.0 / policy_hz
    steps_per_s = num_steps / timing["run_s"]
    return {
        "available": True,
        "implementation": f"highway-env {version} {HIGHWAY_ENV_ID}, one env",
        "step": f"one decision ({seconds_per_step:g} s, {sim_hz / policy_hz:g} sim steps)",
        "version": version,
        "env_id": HIGHWAY_ENV_ID,
        "observation_config": HIGHWAY_OBSERVATION,
        "observation_shape": list(np.shape(obs)),
        "simulation_frequency_hz": sim_hz,
        "policy_frequency_hz": policy_hz,
        "episode_duration_s": config["duration"],
        "num_envs": 1,
        "steps_per_call": num_steps,
        "seconds_per_step": seconds_per_step,
        "setup_s": setup_s,
        **timing,
        "episodes_ended": episodes[0],
        "steps_per_s": steps_per_s,
        "sim_s_per_wall_s": steps_per_s * seconds_per_step,
        "cores_used": _mean(timing["cores_used_per_call"]),
        "warnings": messages,
    }


def ratios(ours: dict[str, Any], other: dict[str, Any]) -> dict[str, float]:
    """Ours over ``other``: per (decision) step and per simulated second."""
    return {
        "per_step": ours["steps_per_s"] / other["steps_per_s"],
        "per_simulated_s": ours["sim_s_per_wall_s"] / other["sim_s_per_wall_s"],
    }


def targets(results: dict[str, dict[str, Any]], ratio: dict[str, dict[str, float]]) -> list[dict]:
    """The target, ours >= 10,000 × highway-env per decision step, with its measured
    ratio and ``met`` (None: not measured)."""
    out = []
    for name, target, what in (
        ("highway-env", TARGET_VS_HIGHWAY, "highway-env, per decision step"),
    ):
        measured = ratio[name]["per_step"] if name in ratio else None
        out.append(
            {
                "peer": name,
                "description": f"ours >= {target:,.0f} × {what}",
                "target": target,
                "measured": measured,
                "met": None if measured is None else measured >= target,
                "reason": None if name in ratio else results[name].get("reason"),
            }
        )
    return out


def target_lines(items: Sequence[dict[str, Any]]) -> list[str]:
    """One line per target: measured ratio and met / missed (or why it was not measured)."""
    lines = []
    for t in items:
        if t["met"] is None:
            lines.append(f"- target: {t['description']}: not measured ({t['reason']})")
        else:
            verdict = "met" if t["met"] else "missed"
            lines.append(
                f"- target: {t['description']}: measured {t['measured']:,.1f} × ({verdict})"
            )
    return lines


COLUMNS = {
    "implementation": "implementation",
    "step": "what a step is",
    "steps_per_s": "steps/s",
    "sim_s_per_wall_s": "simulated s per wall s",
    "ratio_per_step": "ours / it, per step",
    "ratio_per_sim_s": "ours / it, per simulated s",
    "cores_used": "cores used",
}


def table_rows(
    results: dict[str, dict[str, Any]], ratio: dict[str, dict[str, float]]
) -> list[dict[str, Any]]:
    """The rows of the Markdown table, ours first."""
    rows = []
    for name, r in results.items():
        if not r["available"]:
            rows.append(
                {"implementation": r["implementation"], "step": "–", "steps_per_s": "unavailable"}
            )
            continue
        row = {k: r[k] for k in ("implementation", "step", "steps_per_s", "sim_s_per_wall_s")}
        row["cores_used"] = r["cores_used"]
        if name == "ours":
            row["ratio_per_step"] = row["ratio_per_sim_s"] = "1"
        else:
            row["ratio_per_step"] = ratio[name]["per_step"]
            row["ratio_per_sim_s"] = ratio[name]["per_simulated_s"]
        rows.append(row)
    return rows


def parse_args(argv: Sequence[str] | None = None) -> Any:
    """The options; sizes left unset take ``--quick``'s or the full run's defaults."""
    parser = harness.base_parser("peers", __doc__)
    parser.set_defaults(repeats=None)
    parser.add_argument(
        "--num-envs", type=int, metavar="N", help=f"ours: parallel envs ({FULL['num_envs']})"
    )
    parser.add_argument(
        "--steps", type=int, metavar="T", help=f"ours: steps per timed call ({FULL['steps']})"
    )
    parser.add_argument(
        "--highway-steps",
        type=int,
        metavar="T",
        help=f"highway-env: decision steps per timed call ({FULL['highway_steps']})",
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--no-highway", action="store_true", help="skip highway-env (reported as skipped)"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="small sizes for a smoke run: "
        + ", ".join(f"{k.replace('_', '-')} {v}" for k, v in QUICK.items()),
    )
    args = parser.parse_args(argv)
    for key, value in (QUICK if args.quick else FULL).items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    for key in FULL:
        if getattr(args, key) < 1:
            parser.error(f"--{key.replace('_', '-')} must be >= 1")
    return args


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Run both benchmarks, print the report, return its data."""
    args = parse_args(argv)
    results: dict[str, dict[str, Any]] = {}
    print(f"[ours: {args.num_envs} envs × {args.steps} steps per call]", file=sys.stderr)
    results["ours"] = bench_ours(args.num_envs, args.steps, args.repeats, args.seed)
    if args.no_highway:
        results["highway-env"] = highway_unavailable("skipped (--no-highway)")
    else:
        print(f"[highway-env: {args.highway_steps} decision steps per call]", file=sys.stderr)
        results["highway-env"] = bench_highway(args.highway_steps, args.repeats, args.seed)

    ours = results["ours"]
    ratio = {
        name: ratios(ours, r) for name, r in results.items() if name != "ours" and r["available"]
    }
    goals = targets(results, ratio)

    lines = harness.markdown_table(table_rows(results, ratio), COLUMNS)
    lines.append("")
    lines += target_lines(goals)
    if args.quick:
        lines.append(
            f"- --quick: smoke-run sizes ({args.num_envs} envs); the targets are for the full "
            f"run ({FULL['num_envs']} envs), so a miss here says nothing about them"
        )
    lines.append(
        f"- ours: compile {ours['compile_s']:.2f} s (apart from the timing); steps/s = median "
        f"of {args.repeats} timed calls after 1 warm-up, for every implementation"
    )
    hw = results["highway-env"]
    if hw["available"]:
        lines.append(
            f"- highway-env: simulation {hw['simulation_frequency_hz']} Hz, policy "
            f"{hw['policy_frequency_hz']} Hz (its defaults), episodes of "
            f"{hw['episode_duration_s']} s; OccupancyGrid {tuple(hw['observation_shape'])} "
            f"(features {', '.join(HIGHWAY_OBSERVATION['features'])}; 1 m cells over "
            "[-5, 40] m × [-15, 15] m in the ego's axes)"
        )
    else:
        lines.append(f"- highway-env: unavailable: {hw['reason']}")

    config = {"env_id": ENV_ID, **{k: v for k, v in vars(args).items() if k != "out"}}
    result = {"config": config, "implementations": results, "ratios": ratio, "targets": goals}
    title = f"Peers: {ENV_ID} (JAX) vs highway-env {HIGHWAY_ENV_ID}"
    return harness.report("peers", title, result, lines, args.out, argv)


if __name__ == "__main__":
    main()
