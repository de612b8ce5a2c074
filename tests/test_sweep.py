"""Sweeps: points, programs per shape, runs bit-identical alone and on 4 devices, statistics."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
import pytest

from drqn_jax import cli
from drqn_jax.config import ConfigError
from drqn_jax.sweep import (
    interquartile_mean,
    load_sweep,
    summarize_sweep,
    train_runs,
)
from drqn_jax.train import make_train
from tests.helpers import assert_tree_equal

SWEEP = """
base = "smoke"
[set]
"train.num_episodes" = 4
[axes]
"run.seed" = { start = 0, stop = 2 }
"train.learning_rate" = [1e-3, 3e-4]
"""


@pytest.fixture(scope="module")
def sweep_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep") / "sweep.toml"
    path.write_text(SWEEP)
    return path


@pytest.fixture(scope="module")
def trained(sweep_file):
    """The 4-run sweep on one device, in one program."""
    sweep = load_sweep(sweep_file)
    (points,) = sweep.programs()
    _, params, metrics = train_runs(points)
    return sweep, params, metrics


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
    for point in sweep.points[:2]:  # lr differs: traced hyperparameters, one program
        trainer = make_train(point.config.train_config())
        alone = jax.jit(trainer.train)(point.config.keys()[0])
        assert_tree_equal(alone, jax.tree.map(lambda x, i=point.index: x[i], (params, metrics)))


def _train_on_forced_devices(sweep_file: Path, devices: int, out: Path) -> list[np.ndarray]:
    """Leaves of the sweep's first 3 runs trained in a process with ``devices`` forced
    host devices (the runs sharded over all of them, padded to a multiple)."""
    script = textwrap.dedent(f"""
        import jax, numpy as np
        import drqn_jax
        from drqn_jax.sweep import load_sweep, train_runs
        assert len(jax.devices()) == {devices}, jax.devices()
        sweep = load_sweep({str(sweep_file)!r})
        _, params, metrics = train_runs(sweep.points[:3])
        np.savez({str(out)!r}, *jax.tree.leaves((params, metrics)))
    """)
    env = {**os.environ, "XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}"}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    saved = np.load(out)
    return [saved[f"arr_{i}"] for i in range(len(saved.files))]


def _first_three(trained) -> list[np.ndarray]:
    _, params, metrics = trained
    return jax.tree.leaves(jax.tree.map(lambda x: x[:3], (params, metrics)))


@pytest.fixture(scope="module")
def four_devices(sweep_file, tmp_path_factory):
    return _train_on_forced_devices(sweep_file, 4, tmp_path_factory.mktemp("four") / "r.npz")


def test_two_forced_devices_give_bit_identical_runs(sweep_file, trained, tmp_path):
    """3 runs padded to 4, sharded over 2 host devices ≡ the one-device program, bit for bit."""
    two = _train_on_forced_devices(sweep_file, 2, tmp_path / "two.npz")
    one = _first_three(trained)
    assert len(two) == len(one)
    for got, want in zip(two, one, strict=True):
        np.testing.assert_array_equal(got, want, strict=True)


def test_four_forced_devices_shard_and_unpad_the_runs(trained, four_devices):
    """Sharding over 4 devices runs the same 3 runs, in order, padding dropped
    (equal up to float rounding: see the next test)."""
    one = _first_three(trained)
    assert len(four_devices) == len(one)
    for got, want in zip(four_devices, one, strict=True):
        assert got.shape == want.shape and got.dtype == want.dtype
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)


@pytest.mark.xfail(
    strict=True,
    reason="NOT YET: with 4 forced host devices on a 2-core machine (more devices than "
    "cores), XLA:CPU rounds dots with a long contraction (e.g. the conv-1 weight gradient, "
    "192 x 1400 x 32) differently than with 1 or 2 devices, even for a one-device program; "
    "see the issue 6 note",
)
def test_four_forced_devices_give_bit_identical_runs(trained, four_devices):
    for got, want in zip(four_devices, _first_three(trained), strict=True):
        np.testing.assert_array_equal(got, want, strict=True)


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


def test_statistics_are_computed_from_the_runs():
    results = [
        {"values": {"run.seed": s, "train.gamma": g}, **dict.fromkeys(_metrics(), float(v))}
        for s, g, v in [(0, 0.9, 1.0), (1, 0.9, 2.0), (2, 0.9, 6.0), (0, 0.5, 3.0)]
    ]
    rows = summarize_sweep(results)
    assert [r["setting"] for r in rows] == [{"train.gamma": 0.9}, {"train.gamma": 0.5}]
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
    from drqn_jax.sweep import TABLE_METRICS

    return TABLE_METRICS


def test_cli_sweep_writes_tables(sweep_file, tmp_path, capsys):
    assert cli.main(["sweep", str(sweep_file), "--dry-run"]) == 0
    assert "sweep over 4 runs" in capsys.readouterr().err
    out = tmp_path / "out"
    code = cli.main(["sweep", str(sweep_file), "--set", "evaluate.episodes=2", "--out", str(out)])
    assert code == 0
    runs = json.loads((out / "runs.json").read_text())
    assert [r["index"] for r in runs] == [0, 1, 2, 3]
    assert all(r["num_episodes"] == 2 for r in runs)
    csv = (out / "results.csv").read_text().splitlines()
    assert csv[0].startswith("train.learning_rate,runs,collision_free_rate_mean")
    assert len(csv) == 3
    assert "| 0.001 | 2 |" in (out / "results.md").read_text()
    assert Path(out / "results.md").read_text() in capsys.readouterr().out + "\n"
