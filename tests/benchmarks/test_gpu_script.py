"""``benchmarks/gpu.sh`` at tiny sizes (``GPU_DRY_RUN=1``): every GPU figure's command
runs on the CPU and writes its JSON, so a few minutes of GPU are not spent on a typo."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _dry_run(script: str, out: Path, variable: str, timeout: int):
    """``benchmarks/<script> OUT`` with ``variable=1`` (its dry run), this interpreter."""
    return subprocess.run(
        ["bash", str(ROOT / "benchmarks" / script), str(out)],
        cwd=ROOT,
        env={**os.environ, variable: "1", "PYTHON": sys.executable},
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_gpu_script_dry_run_writes_the_throughput_and_the_curve(tmp_path):
    done = _dry_run("gpu.sh", tmp_path, "GPU_DRY_RUN", 600)
    assert done.returncode == 0, done.stderr[-3000:]
    (alone,) = json.loads((tmp_path / "throughput" / "train_throughput.json").read_text())["rows"]
    seeds = json.loads((tmp_path / "seeds" / "train_throughput.json").read_text())
    (row,) = seeds["rows"]
    assert (alone["algorithm"], alone["seeds"]) == ("pqn", 1)
    assert (row["algorithm"], row["seeds"]) == ("pqn", 2)
    assert row["env_steps"] == 2 * alone["env_steps"] == 2 * row["num_envs"] * 8  # 8-step rollouts
    assert row["env_steps_per_s"] > 0 and row["grad_steps"] > 0
    assert seeds["machine"]["git_commit"]
    curve = json.loads((tmp_path / "curve" / "learning_curve.json").read_text())
    assert curve["status"] == "finished"
    assert [p["env_steps"] for p in curve["points"]] == [48, 96]  # 2 envs x 8 steps a chunk
    for point in curve["points"]:
        assert 0.0 <= point["collision_free_rate"] <= 1.0 and point["avg_speed_kmh"] >= 0.0
    assert "learning curve:" in done.stdout


def test_the_table_script_describes_the_whole_table_without_training(tmp_path, monkeypatch):
    """``benchmarks/table3.sh`` with ``TABLE3_DRY_RUN=1``: the command that trains Table III
    at scale validates every arm's config at its real size and describes its 5 seeds,
    on this device's budget (20M ticks per seed at k = 5 on a CPU), and trains nothing;
    ``TABLE3_GROUP=occluded`` does the same for the occluded world's three arms."""
    out = tmp_path / "table3"
    done = _dry_run("table3.sh", out, "TABLE3_DRY_RUN", 300)
    assert done.returncode == 0, done.stderr[-3000:]
    expected = (
        "Table III at scale on cpu (table3-cpu-k5): 20000000 ticks per seed, a decision every 5"
    )
    assert f"{expected}, into {out}" in done.stdout
    for arm in ("pqn", "pqn-dqn", "pqn-stack", "ppo"):
        assert f"{arm}: sweep over 5 runs from '{arm}': run.seed (5)" in done.stderr
    assert not out.exists()
    monkeypatch.setenv("TABLE3_GROUP", "occluded")
    done = _dry_run("table3.sh", out, "TABLE3_DRY_RUN", 300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "(table3-cpu-k5-occluded)" in done.stdout
    assert "ppo:" not in done.stderr and "pqn-stack: sweep over 5 runs" in done.stderr
    assert not out.exists()


def test_the_curve_reads_the_stored_frontier_of_the_presets_world():
    """``pqn`` trains in ``default``'s world and is evaluated on its episodes, so its
    curve's margins read the frontier that ``drqn-jax frontier`` stored for it."""
    from benchmarks.learning_curve import stored_frontier
    from drqn_jax.config import load_config
    from drqn_jax.experiments.baselines import frontier_key

    assert frontier_key(load_config("pqn")) == frontier_key(load_config("default"))
    record = stored_frontier(load_config("pqn"))
    assert record is not None and record["rule_based"]["points"]
    assert record["episodes"] == 1000 and record["seed"] == 0
    assert stored_frontier(load_config("smoke")) is None


def test_every_learner_is_timed_past_its_warm_up_calls():
    """An on-policy learner is sized to ``--envs`` with a step budget that outlasts the
    timed calls; the replay DRQN keeps its own envs and budget."""
    from benchmarks.train_throughput import learner_config

    pqn = learner_config("pqn", [], 512, 6, quick=False)
    assert pqn["train"]["num_envs"] == 512
    assert pqn["train"]["num_env_steps"] == 6 * 512 * pqn["train"]["rollout_steps"]
    assert pqn["train"]["num_episodes"] >= pqn["train"]["num_env_steps"] // 10
    default = learner_config("default", [], 512, 6, quick=False)
    assert default["train"]["num_envs"] == 32 and default["train"]["num_env_steps"] == 0
    quick = learner_config("ppo", [], None, 6, quick=True)
    assert (quick["train"]["algorithm"], quick["network"]["recurrent"]) == ("ppo", 16)


def test_a_curve_can_stop_after_its_first_marks(capsys):
    """``--first N`` trains to the N-th mark only (the start of a curve, to set beside the
    same run's start on another machine); the point is the full curve's first point
    (the dry run's curve, whose first mark is 48 env steps)."""
    from benchmarks.learning_curve import main

    argv = ["--config", "smoke", "--set", "train.algorithm=pqn", "--set", "train.rollout_steps=8"]
    argv += ["--set", "train.num_minibatches=1", "--set", "train.chunk_iterations=1"]
    argv += ["--set", "train.num_env_steps=96", "--set", "train.num_episodes=64"]
    result = main([*argv, "--points", "2", "--episodes", "4", "--first", "1"])
    assert result["status"] == "first 1 of 2 marks"
    assert [p["env_steps"] for p in result["points"]] == [48]
