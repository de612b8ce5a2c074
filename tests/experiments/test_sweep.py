"""Sweeps: points, programs per shape, runs bit-identical alone and on 4 devices, statistics."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import jax
import numpy as np
import pytest

from drqn_jax import cli
from drqn_jax.config import ConfigError, load_config
from drqn_jax.experiments.frontier import interquartile_mean
from drqn_jax.experiments.host_loop import StopRequest
from drqn_jax.experiments.runner import budget_used
from drqn_jax.experiments.sweep import SweepPoint, budget_warnings, load_sweep, summarize_sweep
from drqn_jax.experiments.sweep_plan import (
    USABLE_FRACTION,
    Call,
    call_size,
    plan_calls,
    resolve_strategy,
    run_memory,
)
from drqn_jax.experiments.sweep_runner import (
    call_programs,
    real_agent_params,
    run_sweep,
    sweep_budgets,
    train_call,
)
from drqn_jax.learners import make_train
from tests.helpers import SMOKE_SWEEP as SWEEP
from tests.helpers import assert_tree_equal, train_alone


def train_runs(points, strategy="auto"):
    """``points`` (one shape) trained in one call on the local devices, no checkpoints:
    ``(params, metrics)`` with NumPy leaves of leading size ``len(points)``."""
    devices = jax.local_devices()
    strategy = resolve_strategy(strategy, devices)
    call = Call(0, tuple(points), call_size(len(points), len(devices), strategy), strategy)
    outcome = train_call(call, devices)
    metrics = jax.tree.map(lambda x: np.asarray(x)[: len(points)], outcome.state.metrics)
    return real_agent_params(call, outcome), metrics


@pytest.fixture(scope="module")
def sweep_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep") / "sweep.toml"
    path.write_text(SWEEP)
    return path


@pytest.fixture(scope="module")
def trained(sweep_file):
    """The 4-run sweep on one device, one run per call (``auto`` on the CPU: ``map``),
    as ``cli_sweep`` trains it: the same compiled programs (``call_programs``), so
    this module compiles them once."""
    sweep = load_sweep(sweep_file)
    (points,) = sweep.programs()
    runs = [train_runs([point]) for point in points]
    params, metrics = jax.tree.map(lambda *x: np.concatenate(x), *runs)
    return sweep, params, metrics


def test_vmap_and_map_give_bit_identical_runs(trained):
    """The batched strategy (what accelerators run) ≡ one run after another."""
    sweep, params, metrics = trained
    params_vmap, metrics_vmap = train_runs(sweep.points, strategy="vmap")
    assert_tree_equal((params_vmap, metrics_vmap), (params, metrics))


def test_points_are_the_product_of_the_axes(sweep_file):
    sweep = load_sweep(sweep_file)
    assert [p.values for p in sweep.points] == [
        {"run.seed": 0, "train.learning_rate": 1e-3},
        {"run.seed": 0, "train.learning_rate": 3e-4},
        {"run.seed": 1, "train.learning_rate": 1e-3},
        {"run.seed": 1, "train.learning_rate": 3e-4},
    ]
    config = sweep.points[3].config
    assert config["run"]["seed"] == 1 and config["train"]["learning_rate"] == 3e-4
    assert config["train"]["num_episodes"] == 4  # from [set]
    assert "one program" in sweep.describe()


def test_ranges_zip_mode_and_errors(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(
        'base = "smoke"\nmode = "zip"\n[axes]\n"train.gamma" = { start = 0.5, stop = 0.9, num = 3 }'
        '\n"run.seed" = { start = 3, stop = 9, step = 2 }\n'
    )
    sweep = load_sweep(path)
    assert [p.values["train.gamma"] for p in sweep.points] == [0.5, 0.7, 0.9]
    assert [p.values["run.seed"] for p in sweep.points] == [3, 5, 7]
    for text, message in [
        ('base = "smoke"\nfoo = 1\n', r"unknown key\(s\) foo"),
        ('base = "smoke"\nmode = "grid"\n', r"mode = 'grid'"),
        ('base = "smoke"\nstrategy = "pmap"\n', r"strategy = 'pmap': must be one of 'auto'"),
        ('base = "smoke"\n[axes]\n"train.gamma" = []\n', r"axes\.train\.gamma = \[\]"),
        ('base = "smoke"\n[axes]\n"train.gamma" = [0.9, 2.0]\n', r"sweep point 1 .*train\.gamma"),
        ('base = "smoke"\n[axes]\n"train.nope" = [1]\n', r"unknown field train\.nope"),
        ('base = "smoke"\nmode = "zip"\n[axes]\n"run.seed" = [1, 2]\n"train.gamma" = [0.5]\n',
         "one length"),
    ]:  # fmt: skip
        path.write_text(text)
        with pytest.raises(ConfigError, match=message):
            load_sweep(path)


def test_each_run_is_bit_identical_to_the_run_alone(trained):
    sweep, params, metrics = trained
    point = sweep.points[3]  # the last run: seed and learning rate (traced) differ from run 0
    alone = train_alone(point)
    assert_tree_equal(alone, jax.tree.map(lambda x: x[3], (params, metrics)))


def _other_thread_pool() -> str:
    """A ``PJRT_NPROC`` that gives a subprocess a bigger XLA:CPU thread pool than
    this process's, whatever the machine (at least twice as big, at least 4): the
    pool has max(PJRT_NPROC, forced devices) threads, and Eigen splits a product's
    sums by it (the network's products avoid Eigen,
    :func:`drqn_jax.layers._rows_product`, so results must not depend on it).
    On a 2-core machine that is the pool of 4 that 4 forced devices get anyway."""
    from drqn_jax.determinism import cpu_thread_pool_size

    return str(max(4, 2 * cpu_thread_pool_size()))


def _bigger_pool_env(xla_flags: str) -> dict[str, str]:
    """This process's environment with ``XLA_FLAGS`` and :func:`_other_thread_pool`."""
    env = {**os.environ, "XLA_FLAGS": xla_flags, "PJRT_NPROC": _other_thread_pool()}
    env.pop("NPROC", None)
    return env


def _train_on_forced_devices(
    sweep_file: Path, devices: int, out: Path, jobs: dict[str, int], sweep_args: list[str]
) -> dict[str, list[np.ndarray]]:
    """Leaves of the sweep's first runs trained in one process with ``devices`` forced
    host devices and a bigger XLA:CPU thread pool than this process's
    (:func:`_other_thread_pool`): per job ``{strategy: runs}``, the first ``runs``
    points as one sweep call sharded over all the devices (``"map"`` or
    ``"vmap"``). The same process then runs ``drqn-jax sweep FILE *sweep_args
    --out out/sweep`` (the command a user runs; it shares the map job's programs)."""
    script = textwrap.dedent(f"""
        import jax, numpy as np
        import drqn_jax
        from drqn_jax import cli
        from drqn_jax.experiments.sweep import load_sweep
        from tests.experiments.test_sweep import train_runs
        assert len(jax.devices()) == {devices}, jax.devices()
        sweep = load_sweep({str(sweep_file)!r})
        for strategy, runs in {jobs!r}.items():
            params, metrics = train_runs(sweep.points[:runs], strategy=strategy)
            np.savez(f"{out}/{{strategy}}.npz", *jax.tree.leaves((params, metrics)))
        args = ["sweep", {str(sweep_file)!r}, *{sweep_args!r}, "--out", {str(out / "sweep")!r}]
        assert cli.main([*args, "--quiet"]) == 0
    """)
    env = _bigger_pool_env(f"--xla_force_host_platform_device_count={devices}")
    root = Path(__file__).parents[2]  # the script imports train_runs from this module
    command = [sys.executable, "-c", script]
    done = subprocess.run(command, env=env, cwd=root, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    saved = {strategy: np.load(out / f"{strategy}.npz") for strategy in jobs}
    return {k: [v[f"arr_{i}"] for i in range(len(v.files))] for k, v in saved.items()}


#: Runs per strategy on 4 forced devices: ``map`` one per device, ``vmap`` 3 padded to 8.
FOUR_DEVICE_JOBS = {"map": 4, "vmap": 3}

#: The command-line sweeps' settings (``cli_sweep`` and the 4-device one).
CLI_SWEEP_ARGS = ["--set", "evaluate.episodes=2"]


@pytest.fixture(scope="module")
def on_four_devices(sweep_file, tmp_path_factory):
    """Both strategies of ``FOUR_DEVICE_JOBS`` and the command-line sweep, in one
    process (one start-up, the map job's programs compiled once): ``(leaves per
    strategy, the sweep's output directory)``."""
    out = tmp_path_factory.mktemp("four")
    leaves = _train_on_forced_devices(sweep_file, 4, out, FOUR_DEVICE_JOBS, CLI_SWEEP_ARGS)
    return leaves, out / "sweep"


@pytest.mark.parametrize(("strategy", "runs"), FOUR_DEVICE_JOBS.items())
def test_four_forced_devices_reproduce_each_run_alone(trained, on_four_devices, strategy, runs):
    """The sweep's first ``runs`` points sharded over 4 forced host devices
    (``map``: one run per device; ``vmap``: 3 runs padded to 2 per device, 5 of
    the 8 padding) ≡ each point trained in a call of its own on one device in
    this process (≡ alone, ``test_each_run_is_bit_identical_to_the_run_alone``),
    bit for bit, although the two processes' XLA:CPU thread pools differ."""
    _, params, metrics = trained
    four = on_four_devices[0][strategy]
    one = jax.tree.leaves((params, metrics))
    assert len(four) == len(one)
    for got, want in zip(four, one, strict=True):
        assert len(got) == runs
        np.testing.assert_array_equal(got, want[:runs], strict=True)


def _merged_call_results(out: Path) -> list[dict]:
    """Every call's ``runs.json`` of a sweep's output, in run order."""
    paths = sorted(out.glob("calls/*/runs.json"))
    runs = [run for path in paths for run in json.loads(path.read_text())]
    return sorted(runs, key=lambda r: r["index"])


def assert_same_sweep_outputs(got: Path, want: Path) -> None:
    """Every file two sweeps of the same points wrote is the same, byte for byte:
    the tables, ``runs.json``, each run's metrics CSV, config and agent (every array
    of ``agent.npz`` compared by name first, for the message). ``calls/`` is named
    after the plan's calls (the device and process counts group runs differently):
    their results are compared merged; the plans by their points."""

    def files(out: Path) -> dict[str, Path]:
        skipped = ("calls/", "plan.")
        return {
            p.relative_to(out).as_posix(): p
            for p in sorted(out.rglob("*"))
            if p.is_file() and not p.relative_to(out).as_posix().startswith(skipped)
        }

    got_files, want_files = files(got), files(want)
    assert sorted(got_files) == sorted(want_files)
    assert any(name.startswith("metrics/") for name in want_files)
    assert any(name.endswith("agent.npz") for name in want_files)
    for name, path in want_files.items():
        if name.endswith(".npz"):
            with np.load(path) as a, np.load(got_files[name]) as b:
                assert a.files == b.files, name
                for array in a.files:
                    if not array.endswith("manifest.json"):
                        np.testing.assert_array_equal(b[array], a[array], f"{name}: {array}")
        assert got_files[name].read_bytes() == path.read_bytes(), name
    assert _merged_call_results(got) == _merged_call_results(want)
    [plan] = want.glob("plan*.json")
    for other in got.glob("plan*.json"):
        assert json.loads(other.read_text())["points"] == json.loads(plan.read_text())["points"]


def test_a_sweep_on_four_forced_devices_writes_the_same_files(on_four_devices, cli_sweep):
    """``drqn-jax sweep`` under ``--xla_force_host_platform_device_count=4`` (one call
    of 4 runs, one per device) writes every file as the one-device sweep does (4
    calls of one run), although the two processes' XLA:CPU thread pools differ
    (on this project's 2 cores: 4 threads against 2, as for a user who adds the flag)."""
    assert_same_sweep_outputs(on_four_devices[1], cli_sweep)


def test_a_shape_changing_axis_splits_the_programs(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(
        'base = "smoke"\n[axes]\n"network.hidden" = [8, 16]\n"train.gamma" = [0.5, 0.9]\n'
        '"env.ped_speed_max" = [0.3, 0.4]\n'
    )
    sweep = load_sweep(path)
    programs = sweep.programs()
    assert len(programs) == 2 and [len(p) for p in programs] == [4, 4]
    assert {p.values["network.hidden"] for p in programs[0]} == {8}
    description = sweep.describe()
    assert "2 separate programs: network.hidden change(s) shapes" in description


def test_the_progress_bar_counts_env_steps_where_every_run_has_a_step_budget(sweep_file):
    """A sweep whose runs end at ``train.num_env_steps`` counts env steps (a run's
    episodes lengthen as it learns: an episode bar's rate and estimate mislead), else
    episodes; a call's progress is its real runs' (padding left out), each up to its
    budget."""
    step_budget = ("train.num_env_steps=3000", "train.snapshots=0")
    for overrides, unit in (((), "ep"), (step_budget, "step")):
        sweep = load_sweep(sweep_file, overrides)
        train = sweep.points[0].config["train"]
        per_run = train["num_env_steps"] if unit == "step" else train["num_episodes"]
        calls = plan_calls(sweep, 1)
        budgets, got_unit = sweep_budgets(calls)
        assert got_unit == unit and budgets == [per_run * len(c.points) for c in calls]
        assert sum(budgets) == per_run * len(sweep.points)
    batched = SimpleNamespace(env_steps=np.array([120, 400, 999]), recorded=np.array([2, 9, 9]))
    assert budget_used(batched, 300, "step", runs=2) == 120 + 300
    assert budget_used(batched, 6, "ep", runs=2) == 2 + 6
    assert budget_used(SimpleNamespace(env_steps=np.int32(50)), 300, "step") == 50


def test_calls_that_differ_in_hyperparameter_values_share_their_programs(sweep_file):
    """The hyperparameters are arguments of a call's programs: a sweep over learning
    rates traces and compiles them once per process (with no persistent cache, or in a
    process that does not write it, every call would compile again)."""
    first, second = (make_train(p.config.train_config()) for p in load_sweep(sweep_file).points[:2])
    assert first.config != second.config  # learning rates 1e-3 and 3e-4
    devices = jax.devices()[:1]
    assert call_programs(first, 1, devices, "map") is call_programs(second, 1, devices, "map")
    shorter = make_train(dataclasses.replace(first.config, chunk_iterations=8))
    assert call_programs(shorter, 1, devices, "map") is not call_programs(first, 1, devices, "map")


def test_statistics_are_computed_from_the_runs():
    results = [
        {
            "values": {"run.seed": s, "train.gamma": g},
            "teacher": "imitation" if g == 0.5 else "none (reward alone)",
            "diverged": False,
            **dict.fromkeys(_metrics(), float(v)),
        }
        for s, g, v in [(0, 0.9, 1.0), (1, 0.9, 2.0), (2, 0.9, 6.0), (0, 0.5, 3.0)]
    ]
    rows = summarize_sweep(results)
    assert [r["setting"] for r in rows] == [{"train.gamma": 0.9}, {"train.gamma": 0.5}]
    assert [r["teacher"] for r in rows] == ["none (reward alone)", "imitation"]
    m = rows[0]["collision_free_rate"]
    assert rows[0]["runs"] == 3 and m["mean"] == 3.0
    std = math.sqrt(((1 - 3) ** 2 + (2 - 3) ** 2 + (6 - 3) ** 2) / 2)
    assert m["std"] == pytest.approx(std)
    half = 4.303 * std / math.sqrt(3)  # t(0.975, 2 degrees of freedom)
    assert m["ci95"] == pytest.approx((3.0 - half, 3.0 + half))
    assert math.isnan(rows[1]["collision_free_rate"]["std"])
    assert interquartile_mean(np.array([1.0, 2.0, 3.0, 100.0])) == pytest.approx(2.5)
    # n = 3: the middle half is [0.75, 2.25] of the ranks: (0.25·1 + 2 + 0.25·6) / 1.5
    assert interquartile_mean(np.array([1.0, 2.0, 6.0])) == pytest.approx(2.5)


def _metrics():
    from drqn_jax.experiments.sweep import TABLE_METRICS

    return TABLE_METRICS


def test_cli_sweep_writes_tables(sweep_file, cli_sweep, capsys):
    assert cli.main(["sweep", str(sweep_file), "--dry-run"]) == 0
    err = capsys.readouterr().err
    assert "sweep over 4 runs" in err and "memory plan (1 device(s))" in err
    # auto on the CPU: map, one run per call
    assert "4 calls runs-0000-0000 … runs-0003-0003: 1 run(s) each, map," in err
    assert cli.main(["sweep", str(sweep_file), "--dry-run", "--strategy", "vmap"]) == 0
    assert "4 run(s), vmap," in capsys.readouterr().err
    runs = json.loads((cli_sweep / "runs.json").read_text())
    assert [r["index"] for r in runs] == [0, 1, 2, 3]
    assert all(r["num_episodes"] == 2 and r["diverged"] is False for r in runs)
    # each run's agent chosen between its snapshot and its final parameters
    assert all(len(r["validation_returns"]) == 2 and r["selected"] in (0, 1) for r in runs)
    assert all(
        len(r["validation_collision_free"]) == len(r["validation_speed_kmh"]) == 2 for r in runs
    )
    csv = (cli_sweep / "results.csv").read_text().splitlines()
    assert csv[0].startswith("train.learning_rate,runs,diverged,collision_free_rate_mean")
    assert len(csv) == 3
    assert "| 0.001 | 2 | none (reward alone) |" in (cli_sweep / "results.md").read_text()
    assert all(r["teacher"] == "none (reward alone)" for r in runs)
    assert not list(cli_sweep.glob("calls/*/checkpoint.npz"))  # the results replaced them


@pytest.fixture(scope="module")
def cli_sweep(sweep_file, tmp_path_factory):
    """The 4-run sweep through the command line, one process: its output directory."""
    out = tmp_path_factory.mktemp("cli") / "out"
    code = cli.main(["sweep", str(sweep_file), *CLI_SWEEP_ARGS, "--out", str(out), "--quiet"])
    assert code == 0
    return out


def test_two_processes_on_localhost_match_one_process(sweep_file, cli_sweep, tmp_path):
    """2 processes (jax.distributed on localhost), 2 runs each, with a bigger XLA:CPU
    thread pool than this process's; process 0 gathers the results: every file
    equal to the one-process sweep's (each process keeps the agents and metrics it
    trained)."""
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    out = tmp_path / "out"
    command = [sys.executable, "-m", "drqn_jax.cli", "sweep", str(sweep_file), "--quiet"]
    command += [*CLI_SWEEP_ARGS, "--out", str(out)]
    command += ["--coordinator", f"localhost:{port}", "--num-processes", "2"]
    env = _bigger_pool_env("")
    procs = [
        subprocess.Popen(
            [*command, "--process-id", str(i)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    for i, proc in enumerate(procs):
        _, stderr = proc.communicate(timeout=600)
        assert proc.returncode == 0, f"process {i}: {stderr[-3000:]}"
    assert "process 1 of 2" in stderr  # the last one's plan
    assert (out / "plan.process-0.json").is_file() and (out / "plan.process-1.json").is_file()
    assert_same_sweep_outputs(out, cli_sweep)


def test_an_interrupted_call_resumes_bit_identically(sweep_file, trained, tmp_path):
    sweep, params, metrics = trained
    call = Call(0, tuple(sweep.points), 4)
    stop = StopRequest()

    def interrupt(state):
        stop.signal = 2  # as SIGINT's handler would, after the first chunk

    first = train_call(call, jax.devices(), directory=tmp_path, stop=stop, on_chunk=interrupt)
    assert first.status == "interrupted" and (tmp_path / "checkpoint.npz").is_file()
    assert not bool(jax.numpy.all(first.state.finished))
    resumed = train_call(call, jax.devices(), directory=tmp_path)
    assert resumed.status == "finished"
    assert 0 < first.wall_time_s < resumed.wall_time_s  # the checkpoint carries it on
    chosen = jax.vmap(resumed.trainer.agent_params)(resumed.state)  # the sweep keeps a snapshot
    assert_tree_equal((chosen, resumed.state.metrics), (params, metrics))


def test_resume_skips_finished_calls_and_refuses_another_sweep(sweep_file, cli_sweep, capsys):
    sweep = load_sweep(sweep_file, ["evaluate.episodes=2"])
    outcome = run_sweep(sweep, cli_sweep, resume=True, quiet=True)  # no training: all ended
    assert outcome.status == "finished"
    assert outcome.results == json.loads((cli_sweep / "runs.json").read_text())
    code = cli.main(
        ["sweep", str(sweep_file), "--set", "train.gamma=0.5", "--out", str(cli_sweep), "--resume"]
    )
    assert code == 2
    assert "holds another sweep: point 0" in capsys.readouterr().err
    code = cli.main(["sweep", str(sweep_file), "--out", str(cli_sweep)])
    assert code == 2 and "already holds a sweep" in capsys.readouterr().err


def test_a_sweep_grows_by_seeds_and_keeps_its_runs(sweep_file, cli_sweep, tmp_path, capsys):
    """Seed 0's sweep resumed with both seeds: seed 0's calls are kept, seed 1's train,
    and runs.json is the full sweep's; the full sweep's directory refuses the smaller file."""
    first = tmp_path / "seed0.toml"
    first.write_text(SWEEP.replace("stop = 2", "stop = 1"))
    out = tmp_path / "out"
    args = ["--set", "evaluate.episodes=2", "--out", str(out), "--quiet"]
    assert cli.main(["sweep", str(first), *args, "--no-agents"]) == 0
    assert not (out / "agents").exists()
    kept = {p: p.stat().st_mtime_ns for p in out.glob("calls/*/runs.json")}
    assert len(kept) == 2
    assert cli.main(["sweep", str(sweep_file), *args, "--resume"]) == 0
    assert all(p.stat().st_mtime_ns == t for p, t in kept.items())  # not trained again
    assert sorted(p.name for p in out.glob("agents/*")) == ["run-0002", "run-0003"]
    assert len(json.loads((out / "plan.json").read_text())["points"]) == 4
    assert json.loads((out / "runs.json").read_text()) == json.loads(
        (cli_sweep / "runs.json").read_text()
    )
    capsys.readouterr()
    code = cli.main(["sweep", str(first), "--out", str(cli_sweep), "--resume", "--quiet"])
    assert code == 2
    assert "point 2 ({'run.seed': 1" in capsys.readouterr().err


def test_the_memory_plan_splits_or_refuses(sweep_file, capsys):
    sweep = load_sweep(sweep_file)
    per_run = run_memory(sweep.points[0].config)
    batched = int(2.5 * per_run.total / USABLE_FRACTION)  # vmap: all temporaries at once
    state = per_run.total - per_run.activations
    one_by_one = int((per_run.activations + 2 * 2.5 * state) / USABLE_FRACTION)  # map
    for strategy, budget in [("vmap", batched), ("map", one_by_one)]:
        calls = plan_calls(sweep, 1, budget=budget, strategy=strategy)
        per_call = 2 if strategy == "vmap" else 1  # map: one run per device and call
        assert [len(c.points) for c in calls] == [per_call] * (4 // per_call)
        assert all(c.size == per_call for c in calls)
        assert [p.index for c in calls for p in c.points] == [0, 1, 2, 3]
    assert [len(c.points) for c in plan_calls(sweep, 1, budget=10**12, strategy="vmap")] == [4]
    assert [len(c.points) for c in plan_calls(sweep, 1, budget=10**12)] == [1, 1, 1, 1]  # map
    code = cli.main(["sweep", str(sweep_file), "--memory-gb", "0.001", "--dry-run"])
    assert code == 2
    err = capsys.readouterr().err
    assert "memory plan: one run needs" in err and "replay" in err and "--memory-gb" in err


def test_vmap_calls_never_hold_one_run_per_device():
    assert [call_size(n, 1) for n in (1, 2, 3)] == [2, 2, 3]
    assert [call_size(n, 4) for n in (1, 4, 5, 8, 9)] == [8, 8, 8, 8, 12]
    assert call_size(3, 4, most_per_device=1) == 4  # memory allows no more
    assert [call_size(n, 4, "map") for n in (1, 4, 5)] == [4, 4, 8]  # unbatched: as alone


def test_the_thread_pool_size_follows_pjrt_nproc_and_forced_devices(monkeypatch):
    from drqn_jax.determinism import cpu_thread_pool_size

    monkeypatch.setenv("PJRT_NPROC", "3")
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=4")
    assert cpu_thread_pool_size() == 4
    monkeypatch.setenv("PJRT_NPROC", "6")
    assert cpu_thread_pool_size() == 6
    monkeypatch.delenv("XLA_FLAGS")
    monkeypatch.delenv("PJRT_NPROC")
    monkeypatch.delenv("NPROC", raising=False)
    assert cpu_thread_pool_size() == len(os.sched_getaffinity(0))


def test_several_processes_need_all_three_settings(monkeypatch):
    from drqn_jax.experiments.sweep_plan import Distributed, init_distributed

    for name in ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID"):
        monkeypatch.delenv(name, raising=False)
    assert init_distributed(None, None, None) == Distributed(0, 1)
    monkeypatch.setenv("JAX_COORDINATOR_ADDRESS", "localhost:1")
    with pytest.raises(ConfigError, match="need all three"):
        init_distributed(None, 2, None)
    monkeypatch.setenv("JAX_PROCESS_ID", "two")
    with pytest.raises(ConfigError, match="JAX_PROCESS_ID = 'two'"):
        init_distributed(None, 2, None)
    with pytest.raises(ConfigError, match="0 <= process_id < num_processes"):
        init_distributed(None, 2, 2)


def test_every_run_writes_its_training_metrics(trained, cli_sweep):
    """OUT/metrics/run-NNNN.csv: each run's metrics.csv, as ``drqn-jax train`` writes it."""
    from drqn_jax.experiments.runner import metrics_csv
    from drqn_jax.experiments.sweep_outputs import metrics_path

    sweep, _, metrics = trained
    for point in sweep.points:
        run_metrics = {name: values[point.index] for name, values in metrics.items()}
        text = metrics_path(cli_sweep, point.index).read_text()
        assert text == metrics_csv(run_metrics)
        assert len(text.splitlines()) == 1 + 4  # header + train.num_episodes rows


def test_the_final_training_return_is_of_the_recorded_episodes(trained, cli_sweep):
    """The mean return of the last tenth of the episodes a run recorded, not of the
    ``num_episodes`` slots a step budget leaves mostly empty (every run of a step budget
    reported 0.0 before); in runs.json, each run's own."""
    from drqn_jax.experiments.runner import final_train_return

    length = np.zeros(200, np.int32)
    length[:25] = 7
    length[[3, 21]] = 0  # episodes still running when the run stopped
    returns = np.where(length > 0, np.arange(200, dtype=np.float32), np.float32(0))
    metrics = {"episode_return": returns, "length": length}
    assert final_train_return(metrics) == 23.5  # 23 recorded: the last 2, slots 23 and 24
    assert np.isnan(final_train_return({"episode_return": returns, "length": 0 * length}))
    _, _, metrics = trained
    runs = json.loads((cli_sweep / "runs.json").read_text())
    for run in runs:
        mine = {name: values[run["index"]] for name, values in metrics.items()}
        assert run["final_train_return"] == final_train_return(mine) != 0.0


def test_a_run_its_episode_cap_ended_before_its_step_budget_is_named():
    """A step-budget run that stopped at ``train.num_episodes`` (recurrent PPO's cap of
    2048 ended a 6M-step Table III run at 1.19M) gets a warning; one that spent its
    budget, a diverged one and an episode-budget one get none."""
    config = load_config("smoke", ("train.num_env_steps=1000",))
    points = [SweepPoint(i, {"run.seed": i}, config) for i in range(3)]
    runs = [
        {"env_steps": 400, "diverged": False},
        {"env_steps": 1024, "diverged": False},
        {"env_steps": 200, "diverged": True},
    ]
    (line,) = budget_warnings(points, runs)
    assert line.startswith("warning: run 0 ended at train.num_episodes = 6 after 400 of its 1,000")
    episodes = SweepPoint(0, {}, load_config("smoke"))
    assert budget_warnings([episodes], runs[:1]) == []


def test_every_run_keeps_its_trained_agent(trained, cli_sweep, tmp_path, capsys):
    """OUT/agents/run-NNNN holds the run's agent bit for bit; ``drqn-jax evaluate``
    reads it like a run directory and scores it as the sweep did."""
    from drqn_jax.experiments.runner import load_run, load_trained_network
    from drqn_jax.experiments.sweep_outputs import agent_dir

    sweep, params, _ = trained
    for point in sweep.points:
        directory = agent_dir(cli_sweep, point.index)
        _, run_params, meta = load_trained_network(load_run(directory), directory)
        assert_tree_equal(run_params, jax.tree.map(lambda x, i=point.index: x[i], params))
        assert meta["values"] == point.values and meta["recorded"] == 4 and meta["finished"]
    # on the sweep's episodes (its first point's evaluation key: seed 0)
    run = json.loads((cli_sweep / "runs.json").read_text())[3]
    out = tmp_path / "evaluation.json"
    directory = agent_dir(cli_sweep, 3)
    assert cli.main(["evaluate", str(directory), "--seed", "0", "--json", str(out)]) == 0
    evaluation = json.loads(out.read_text())
    for name in ("num_episodes", "collision_free_rate", "avg_speed_kmh", "goal_rate"):
        assert evaluation[name] == run[name], name
    # the agent is checked against its config: another training config is refused
    text = (directory / "config.toml").read_text()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "config.toml").write_text(text.replace("seed = 1", "seed = 7"))
    (tmp_path / "other" / "agent.npz").write_bytes((directory / "agent.npz").read_bytes())
    assert cli.main(["evaluate", str(tmp_path / "other")]) == 2
    assert "run.seed" in capsys.readouterr().err


def test_an_exported_sweep_agent_names_where_its_run_trained(cli_sweep, tmp_path):
    """``drqn-jax export OUT/agents/run-NNNN`` keeps the commit and device of the run's
    record (a shipped agent's provenance), not those of the exporting
    checkout: here the record is rewritten to say it trained elsewhere."""
    import shutil

    from drqn_jax.experiments.sweep_outputs import agent_dir, run_record

    out = tmp_path / "out"
    shutil.copytree(cli_sweep, out)
    elsewhere = {"commit": "abc1234", "trained_on": "another machine"}
    for path in out.glob("calls/*/runs.json"):
        runs = [{**r, **elsewhere} if r["index"] == 3 else r for r in json.loads(path.read_text())]
        path.write_text(json.dumps(runs))
    assert run_record(agent_dir(out, 3))["commit"] == "abc1234"
    assert run_record(tmp_path) is None and run_record(out / "agents" / "run-0009") is None
    shipped = tmp_path / "shipped"
    assert (
        cli.main(["export", str(agent_dir(out, 3)), str(shipped), "--command", "c", "--quiet"]) == 0
    )
    provenance = json.loads((shipped / "provenance.json").read_text())
    assert provenance["trained"] == {"commit": "abc1234", "device": "another machine"}
    assert provenance["machine"]["git_commit"]  # the export's own machine block stays
