"""The drqn-jax command line on the smoke config: run directory, resume, signals, errors."""

from __future__ import annotations

import itertools
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from benchmarks.env_throughput import QUICK_ENVS, QUICK_STEPS
from drqn_jax import cli
from drqn_jax.config import load_config
from drqn_jax.env.state import ACTIONS
from drqn_jax.experiments import runner
from drqn_jax.experiments.checkpoint import CHECKPOINT_JSON, CHECKPOINT_NPZ, load_checkpoint
from drqn_jax.experiments.machine import device_identity, git_commit
from tests.helpers import SMOKE_CHUNK, fast_compile_env

SMOKE = ["--config", "smoke", "--quiet"]
RUN_FILES = {
    "config.toml",
    "metrics.csv",
    CHECKPOINT_NPZ,
    CHECKPOINT_JSON,
    "evaluation.json",
    "results.md",
}


def _state(run_dir: Path):
    """The TrainState leaves of a run directory's checkpoint (npz arrays, no manifest)."""
    return {k: v for k, v in np.load(run_dir / CHECKPOINT_NPZ).items() if k != "manifest.json"}


def _assert_same_checkpoint(a: Path, b: Path) -> None:
    sa, sb = _state(a), _state(b)
    assert sa.keys() == sb.keys()
    for name in sa:
        np.testing.assert_array_equal(sa[name], sb[name], err_msg=name, strict=True)


@pytest.fixture(scope="module")
def straight(tmp_path_factory):
    """An uninterrupted smoke run (its training curves in ../training.rrd)."""
    run_dir = tmp_path_factory.mktemp("straight") / "run"
    rrd = run_dir.parent / "training.rrd"
    assert cli.main(["train", *SMOKE, "--run-dir", str(run_dir), "--rrd", str(rrd)]) == 0
    return run_dir


def test_train_writes_the_run_directory(straight, capsys):
    assert {p.name for p in straight.iterdir()} >= RUN_FILES
    assert not [p for p in straight.iterdir() if p.name.endswith(".tmp")]
    rows = (straight / "metrics.csv").read_text().splitlines()
    assert rows[0].split(",") == [
        "episode",
        "episode_return",
        "length",
        "collision",
        "goal",
        "distance",
        "mean_speed",
        "epsilon",
        "mean_loss",
    ]
    assert [int(r.split(",")[0]) for r in rows[1:]] == list(range(6))
    meta = json.loads((straight / CHECKPOINT_JSON).read_text())
    assert meta["finished"] and meta["recorded"] == 6
    assert meta["config_hash"] == load_config(straight / "config.toml").training_hash()
    evaluation = json.loads((straight / "evaluation.json").read_text())
    (drqn,) = evaluation["agents"]
    assert drqn["agent"] == "drqn" and drqn["num_episodes"] == 8
    assert "| drqn | none (reward alone) | 8 |" in (straight / "results.md").read_text()


def test_progress_bar_does_not_change_results(straight, tmp_path, capsys):
    loud = tmp_path / "loud"
    assert cli.main(["train", "--config", "smoke", "--run-dir", str(loud)]) == 0
    _assert_same_checkpoint(straight, loud)
    assert (loud / "metrics.csv").read_text() == (straight / "metrics.csv").read_text()


def _interrupt_after(monkeypatch, chunks: int) -> None:
    """Send SIGINT to this process right after the ``chunks``-th chunk of training."""
    compiled = runner.compiled_run
    calls = {"n": 0}

    def wrapped(trainer, state):
        run = compiled(trainer, state)

        def run_and_signal(s):
            out = run(s)
            calls["n"] += 1
            if calls["n"] == chunks:
                signal.raise_signal(signal.SIGINT)
            return out

        return run_and_signal

    monkeypatch.setattr(runner, "compiled_run", wrapped)


def test_interrupt_then_resume_is_bit_identical(straight, tmp_path, monkeypatch, capsys):
    run_dir = tmp_path / "run"
    handler = signal.getsignal(signal.SIGINT)  # SIG_IGN when the suite runs in the background
    _interrupt_after(monkeypatch, 2)
    assert cli.main(["train", *SMOKE, "--run-dir", str(run_dir)]) == 130
    assert "--resume" in capsys.readouterr().err
    meta = json.loads((run_dir / CHECKPOINT_JSON).read_text())
    assert meta["chunks"] == 2 and not meta["finished"]
    assert not (run_dir / "evaluation.json").exists()
    monkeypatch.undo()
    assert signal.getsignal(signal.SIGINT) is handler  # train restored it
    assert cli.main(["train", "--resume", str(run_dir), "--quiet"]) == 0
    _assert_same_checkpoint(straight, run_dir)
    assert (run_dir / "metrics.csv").read_text() == (straight / "metrics.csv").read_text()
    assert (
        json.loads((run_dir / "evaluation.json").read_text())["agents"]
        == json.loads((straight / "evaluation.json").read_text())["agents"]
    )


#: Recurrent PPO on the smoke config, with a budget of 64 env steps: 4 updates of
#: 2 envs × 8 steps, in 2 chunks.
PPO = [
    *SMOKE,
    *("--set", "train.algorithm=ppo", "--set", "train.num_minibatches=2"),
    *("--set", "train.rollout_steps=8", "--set", "train.num_env_steps=64"),
    *("--set", "train.chunk_iterations=1"),
]


def test_ppo_trains_resumes_bit_identical_and_evaluates(tmp_path, monkeypatch, capsys):
    """``train.algorithm = "ppo"`` runs through the same host loop: the step budget
    ends it, an interrupted run resumes bit for bit, metrics.csv has no ε, and
    its agent is evaluated under its own name."""
    straight, interrupted = tmp_path / "straight", tmp_path / "interrupted"
    assert cli.main(["train", *PPO, "--run-dir", str(straight)]) == 0
    meta = json.loads((straight / CHECKPOINT_JSON).read_text())
    assert meta["finished"] and meta["env_steps"] == 64 and meta["chunks"] == 4
    header = (straight / "metrics.csv").read_text().splitlines()[0].split(",")
    assert "epsilon" not in header and "mean_loss" in header
    (agent,) = json.loads((straight / "evaluation.json").read_text())["agents"]
    assert agent["agent"] == "ppo" and agent["teacher"] == "none (reward alone)"
    _interrupt_after(monkeypatch, 1)
    assert cli.main(["train", *PPO, "--run-dir", str(interrupted)]) == 130
    monkeypatch.undo()
    assert cli.main(["train", "--resume", str(interrupted), "--quiet"]) == 0
    _assert_same_checkpoint(straight, interrupted)
    capsys.readouterr()
    # smoke's 8 episodes: the program the run's own evaluation compiled
    assert cli.main(["evaluate", str(straight), "--episodes", "8"]) == 0
    assert "| ppo | none (reward alone) | 8 |" in capsys.readouterr().out


def test_sigterm_in_a_subprocess_saves_and_exits_130(tmp_path):
    """A real signal from outside, delivered while the process trains (its programs,
    compiled for it alone, without LLVM's optimisation: ``tests.helpers.FAST_COMPILE``)."""
    run_dir = tmp_path / "run"
    cmd = [
        sys.executable,
        "-m",
        "drqn_jax.cli",
        "train",
        *SMOKE,
        "--set",
        "train.num_episodes=4000",
        "--set",
        "train.chunk_iterations=4",
        "--run-dir",
        str(run_dir),
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=fast_compile_env()
    )
    deadline = time.monotonic() + 240
    while not (run_dir / CHECKPOINT_JSON).exists():  # written once compiled
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.2)
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "SIGTERM" in err and "--resume" in err
    config = load_config(run_dir / "config.toml")
    meta = json.loads((run_dir / CHECKPOINT_JSON).read_text())
    assert meta["chunks"] > 0 and meta["recorded"] < 4000
    assert meta["config_hash"] == config.training_hash()


def test_resume_with_other_training_settings_names_the_field(straight, capsys):
    code = cli.main(["train", "--resume", str(straight), "--set", "train.batch_size=2", "--quiet"])
    assert code == 2
    err = capsys.readouterr().err
    assert "train.batch_size" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_resume_errors_are_one_line(tmp_path, capsys):
    assert cli.main(["train", "--resume", str(tmp_path), "--config", "paper"]) == 2
    assert "drop --config" in capsys.readouterr().err
    assert cli.main(["train", "--resume", str(tmp_path / "nothing"), "--quiet"]) == 2
    assert "not a run directory" in capsys.readouterr().err
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.toml").write_text(load_config("smoke").to_toml())
    assert cli.main(["train", "--resume", str(run_dir), "--quiet"]) == 2
    assert "checkpoint" in capsys.readouterr().err


def test_truncated_checkpoint_is_reported(straight, tmp_path, capsys):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    for name in ("config.toml", CHECKPOINT_JSON):
        (run_dir / name).write_bytes((straight / name).read_bytes())
    data = (straight / CHECKPOINT_NPZ).read_bytes()
    (run_dir / CHECKPOINT_NPZ).write_bytes(data[: len(data) // 2])
    assert cli.main(["train", "--resume", str(run_dir), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert CHECKPOINT_NPZ in err and len(err.strip().splitlines()) == 1


def test_a_run_directory_of_an_older_version_is_refused_in_one_line(straight, tmp_path, capsys):
    """A run directory an older version wrote (a format-1 checkpoint, a config.toml
    naming ``env.ped_yield``) is neither resumed nor evaluated: status 2 and one line
    naming what wrote it and what to do."""
    import zipfile

    run_dir = tmp_path / "old"
    run_dir.mkdir()
    toml = (straight / "config.toml").read_text()
    (run_dir / "config.toml").write_text(
        toml.replace('ped_behaviour_to_car = "ignore"', "ped_yield = 0")
    )
    with (
        zipfile.ZipFile(straight / CHECKPOINT_NPZ) as old,
        zipfile.ZipFile(run_dir / CHECKPOINT_NPZ, "w") as new,
    ):
        for info in old.infolist():
            data = old.read(info)
            if info.filename == "manifest.json":
                manifest = json.loads(data)
                del manifest["drqn_jax_commit"]
                data = json.dumps({**manifest, "format": 1, "drqn_jax_version": "0.1.0"})
            new.writestr(info, data)
    for command in (["train", "--resume", str(run_dir)], ["evaluate", str(run_dir)]):
        assert cli.main([*command, "--quiet"]) == 2, command
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "Traceback" not in err, err
        assert "written by drqn_jax 0.1.0 in format 1; this version reads format 2" in err
        assert err.endswith("train it again, or use the commit that wrote it"), err


def test_fresh_run_refuses_a_used_directory(straight, capsys):
    assert cli.main(["train", *SMOKE, "--run-dir", str(straight)]) == 2
    assert "--resume" in capsys.readouterr().err


def test_config_error_exits_2_before_compiling(tmp_path, capsys):
    code = cli.main(
        ["train", *SMOKE, "--set", "train.learning_rate=-1", "--run-dir", str(tmp_path)]
    )
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "train.learning_rate = -1" in err
    assert not list(tmp_path.iterdir())  # nothing written


def test_non_finite_loss_keeps_the_last_good_checkpoint(tmp_path, capsys):
    run_dir = tmp_path / "run"
    code = cli.main(
        ["train", *SMOKE, "--set", "train.learning_rate=1e38", "--run-dir", str(run_dir)]
    )
    assert code == 1
    assert "non-finite" in capsys.readouterr().err
    config = load_config(run_dir / "config.toml")
    trainer = runner.make_train(config.train_config())
    import jax

    template = jax.eval_shape(trainer.init, config.keys()[0])
    state, meta = load_checkpoint(run_dir, template)
    assert not meta["finished"]
    assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree.leaves(state.online))


def test_evaluate_builtin_and_trained(straight, capsys):
    assert cli.main(["evaluate", "--agent", "rule-based", "--episodes", "4", "--json", "-"]) == 0
    captured = capsys.readouterr()
    payload = json.loads(captured.out)  # stdout is only the JSON; the table is on stderr
    assert "| rule-based | – (not learned) | 4 |" in captured.err
    assert payload["agent"] == "rule-based" and payload["num_episodes"] == 4
    assert payload["teacher"] == "– (not learned)"
    assert 0.0 <= payload["collision_free_rate"] <= 1.0
    path = straight.parent / "eval.json"
    assert cli.main(["evaluate", str(straight), "--episodes", "3", "--json", str(path)]) == 0
    assert json.loads(path.read_text())["agent"] == "drqn"
    assert "| drqn | none (reward alone) | 3 |" in capsys.readouterr().out


def test_an_exported_agent_is_shipped_and_evaluates_as_its_run(
    straight, tmp_path, monkeypatch, capsys
):
    """Issue 53: ``export`` writes a finished run's agent alone with its provenance; under
    drqn_jax/agents/trained/NAME it is ``--agent NAME``, the same policy as the run."""
    from drqn_jax.agents import shipped

    out = tmp_path / "trained" / "tiny"
    command = "drqn-jax train --config smoke"
    assert cli.main(["export", str(straight), str(out), "--command", command]) == 0
    files = {p.name for p in out.iterdir()}
    assert files == {"config.toml", "agent.npz", "agent.json", "provenance.json"}
    provenance = json.loads((out / "provenance.json").read_text())
    meta = json.loads((straight / CHECKPOINT_JSON).read_text())
    assert provenance["command"] == command and provenance["env_steps"] == meta["env_steps"]
    assert provenance["wall_time_s"] == meta["wall_time_s"] and provenance["machine"]["git_commit"]
    # a train run (no sweep record) is taken to have trained in this checkout, on this device
    assert provenance["trained"] == {"commit": git_commit(), "device": device_identity()}
    assert (out / "agent.npz").stat().st_size < (straight / CHECKPOINT_NPZ).stat().st_size

    monkeypatch.setattr(shipped, "TRAINED_DIR", tmp_path / "trained")
    assert shipped.shipped_agents() == ("tiny",)
    run, ours = tmp_path / "run.json", tmp_path / "shipped.json"
    assert cli.main(["evaluate", str(straight), "--episodes", "3", "--json", str(run)]) == 0
    assert cli.main(["evaluate", "--agent", "tiny", "--episodes", "3", "--json", str(ours)]) == 0
    assert json.loads(ours.read_text()) == json.loads(run.read_text())
    capsys.readouterr()
    assert cli.main(["evaluate", str(straight), "--agent", "tiny"]) == 2  # one or the other
    assert "--agent tiny is a shipped agent: give no RUN_DIR" in capsys.readouterr().err
    assert cli.main(["export", str(tmp_path), str(tmp_path / "x"), "--command", "c"]) == 2


def _rrd_rows(path: Path) -> dict[str, int]:
    """Temporal rows per entity of a rerun recording."""
    from rerun.chunk import RrdReader

    rows: dict[str, int] = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        if not chunk.is_static:
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    return rows


def test_train_rrd_and_replay_of_the_trained_drqn(straight, capsys):
    curves = _rrd_rows(straight.parent / "training.rrd")
    for name in ("return", "length", "loss", "epsilon", "collision_rate"):
        assert curves[f"/training/{name}"] == 6  # one value per training episode
    out = straight.parent / "replay.rrd"
    assert cli.main(["replay", str(straight), "--episodes", "8", "--out", str(out)]) == 0
    assert "8 episodes of drqn (seed 0)" in capsys.readouterr().out
    rows = _rrd_rows(out)
    lengths = [rows[f"/episode/{i}/action"] for i in range(8)]
    assert all(rows[f"/episode/{i}/q/{a}"] == lengths[i] for i in range(8) for a in ACTIONS)
    assert all(rows[f"/episode/{i}/world/ego"] == lengths[i] + 1 for i in range(8))
    assert "/episode/8/world/ego" not in rows
    # the replayed episodes are the 8 that training's final evaluation played
    evaluation = json.loads((straight / "evaluation.json").read_text())["agents"][0]
    assert np.mean(lengths) == evaluation["avg_length"]


def test_reproduce_prints_table_iii_beside_ours(tmp_path, capsys):
    run_dir = tmp_path / "rep"
    assert cli.main(["reproduce", "--train", *SMOKE, "--run-dir", str(run_dir)]) == 0
    out = capsys.readouterr().out
    assert f"safety/speed figure: {run_dir / 'safety_speed.png'}" in out
    assert (run_dir / "safety_speed.png").read_bytes()[:4] == b"\x89PNG"
    paper_row = "| paper (CARLA) | rule-based | – (not learned) | 1 × 10 |"
    assert paper_row + " 40.0 (16.8–68.7) | – | – | 7.79 |" in out
    assert "| paper (CARLA) | rule-based | – | 82.6 | – | – | – |" in out
    assert "| paper (CARLA) | DRQN | none (reward alone) | 1 × 10 | 70.0 (39.7–89.2) |" in out
    trained = runner.load_trained_network(runner.load_run(run_dir), run_dir)[2]
    steps = f"{trained['env_steps'] / 1e6:.2f}M"
    how = f"1 | {steps} | {steps} | {trained['wall_time_s'] / 60:.1f} | [1] ×1 |"
    assert f"| drqn_jax | drqn | 1 × 8 | {how}" in out
    assert "| drqn_jax | rule-based | – (not learned) | 1 × 8 |" in out
    assert "| rule-based |" not in out[out.index("Training:") :]  # not trained here
    assert "* **margin to the rule-based frontier, points (95 %)**: " in out  # the legend
    assert f"Devices: [1] {device_identity()}." in out
    assert "wall time" in out
    verdict = [line for line in out.splitlines() if line.startswith("The paper's claim")]
    assert len(verdict) == 1 and "One training seed" in verdict[0], out
    assert "points at" in verdict[0]  # judged by its margin to the rule-based frontier
    assert any(word in verdict[0] for word in ("supported:", "reversed:", "not shown:"))
    agents = json.loads((run_dir / "evaluation.json").read_text())["agents"]
    assert [a["agent"] for a in agents] == ["drqn", "rule-based"]


def test_reproduce_evaluates_the_shipped_agent_without_training(
    straight, tmp_path, monkeypatch, capsys
):
    """Issue 53: ``reproduce`` alone evaluates the shipped headline agent (here the smoke
    run, exported) beside the paper and the frontier; it trains nothing."""
    import drqn_jax.experiments.runner as runner
    from drqn_jax.agents import shipped

    monkeypatch.setattr(shipped, "TRAINED_DIR", tmp_path / "trained")
    assert cli.main(["reproduce", "--run-dir", str(tmp_path / "none")]) == 2
    assert "no shipped agent 'headline' (shipped: none)" in capsys.readouterr().err
    command = "drqn-jax train --config smoke"
    assert (
        cli.main(
            ["export", str(straight), str(tmp_path / "trained" / "headline"), "--command", command]
        )
        == 0
    )
    monkeypatch.setattr(runner, "train_run", None)  # must not be called
    run_dir = tmp_path / "rep"
    assert cli.main(["reproduce", "--run-dir", str(run_dir)]) == 0
    captured = capsys.readouterr()
    assert "the shipped agent 'headline': " in captured.err and f"`{command}`" in captured.err
    shipped = json.loads((tmp_path / "trained" / "headline" / "provenance.json").read_text())
    assert "one decision per 0.1 s (1 tick), " in captured.err
    assert shipped["decision_steps"] == 1 and shipped["ticks"] == shipped["env_steps"]
    steps = f"{shipped['env_steps'] / 1e6:.2f}M"
    how = f"1 | {steps} | {steps} | {shipped['wall_time_s'] / 60:.1f} | [1] ×1 |"
    assert f"| drqn_jax | drqn | 1 × 8 | {how}" in captured.out
    assert f"Devices: [1] {device_identity()}." in captured.out  # its machine block's
    assert "\nThe paper's claim" in captured.out
    evaluated = json.loads((run_dir / "evaluation.json").read_text())["agents"][0]
    trained = json.loads((straight / "evaluation.json").read_text())["agents"][0]
    assert evaluated == trained  # the shipped agent is the run's, on the same episodes
    assert cli.main(["reproduce", "--config", "smoke"]) == 2  # --config needs --train


def test_bench_quick_prints_throughput(capsys):
    argv = ["bench", "quick", "--config", "smoke", "--num-envs", "4", "--steps", "5"]
    argv += ["--iterations", str(SMOKE_CHUNK), "--decision-steps", "1", "4"]
    argv += ["--set", "train.num_episodes=40"]  # k = 4's decisions outlast a chunk
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "env steps/s at 4 envs" in out and "JAX" in out
    envs = load_config("smoke")["train"]["num_envs"]
    assert f"gradient updates/s (DQN: {envs} envs" in out
    lines = {k: line for line in out.splitlines() for k in (1, 4) if f"k = {k})" in line}
    for k, line in lines.items():  # ticks/s = k × decisions/s, as printed
        decisions, ticks = re.search(r"([\d,]+) decisions/s = ([\d,]+) ticks/s", line).groups()
        assert abs(int(ticks.replace(",", "")) - k * int(decisions.replace(",", ""))) <= k
    assert set(lines) == {1, 4}


def test_bench_quick_counts_ppos_iterations_in_env_steps_and_updates():
    """Issue 51: a PPO iteration is a rollout and its epochs; bench counts them from the
    state (the PPO config of the test above: its chunk program, one iteration a call)."""
    from drqn_jax.commands.bench import bench_train, train_figures

    overrides = [value for flag, value in itertools.pairwise(PPO) if flag == "--set"]
    config = load_config("smoke", overrides)
    figures = train_figures(config, 1)
    train = config["train"]
    assert figures["env_steps"] == train["rollout_steps"] * train["num_envs"]
    assert figures["grad_steps"] == train["update_epochs"] * train["num_minibatches"]
    assert "gradient updates/s (PPO: a rollout of 8 steps × 2 envs" in bench_train(config, 1)


def test_bench_runs_a_suite_benchmark_and_writes_json_and_markdown(tmp_path, capfd):
    """As a module in a child process; this process's sys.path stays as it was."""
    path = list(sys.path)
    n, steps = QUICK_ENVS, QUICK_STEPS
    argv = ["bench", "env_throughput", "--batch-sizes", str(n), "--steps", str(steps)]
    argv += ["--repeats", "2"]
    assert cli.main([*argv, "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "env_throughput.json").read_text())
    assert result["command"].startswith(f"python -m benchmarks.env_throughput --batch-sizes {n}")
    assert result["machine"]["jax_version"] == jax.__version__
    (row,) = result["rows"]
    assert len(row["run_times_s"]) == 2 and row["run_s"] == np.median(row["run_times_s"])
    assert row["env_steps_per_s"] == pytest.approx(n * steps / row["run_s"])
    md = (tmp_path / "env_throughput.md").read_text()
    assert f"| {n} |" in md and "JAX" in md and md in capfd.readouterr().out
    assert sys.path == path


def test_bench_all_takes_only_the_common_options(capsys):
    with pytest.raises(SystemExit):
        cli.main(["bench", "all", "--batch-sizes", "2"])
    assert "unrecognized arguments: --batch-sizes" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["train", "evaluate", "reproduce", "replay", "bench"])
def test_help_lists_every_option_with_its_default(command, capsys):
    with pytest.raises(SystemExit) as info:
        cli.main([command, "--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    parser = cli.build_parser()
    sub = parser._subparsers._group_actions[0].choices[command]
    for action in sub._actions:
        if action.option_strings and action.dest != "help":
            assert action.option_strings[-1] in text
            if action.default not in (None, False, [], "==SUPPRESS=="):
                assert f"(default: {action.default})" in " ".join(text.split())


def test_every_command_takes_quiet_and_the_program_its_version(capsys):
    parser = cli.build_parser()
    commands = parser._subparsers._group_actions[0].choices
    for name, sub in commands.items():
        if name != "bench":  # bench passes its options to the benchmark it runs
            assert any("--quiet" in a.option_strings for a in sub._actions), name
    with pytest.raises(SystemExit) as info:
        cli.main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.startswith("drqn-jax ")


@pytest.mark.parametrize("command", ["evaluate", "replay", "study"])
def test_help_names_each_default_once(command, capsys):
    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: None)" not in text and "(default: False)" not in text
    # a default the help names already is not repeated
    assert not re.search(r"\(default: [^)]*\) \(default:", text), text


def test_console_script_is_installed():
    script = Path(sys.executable).parent / "drqn-jax"
    out = subprocess.run([str(script), "--help"], capture_output=True, text=True)
    assert out.returncode == 0
    for command in ("train", "evaluate", "reproduce", "replay", "bench"):
        assert command in out.stdout


def test_long_phases_say_what_they_do_unless_quiet(tmp_path, capsys):
    """Issue 42: compiling and evaluating print a line each on stderr; --quiet none."""
    assert cli.main(["train", "--config", "smoke", "--run-dir", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "compiling the training program" in err
    assert "evaluating drqn on 8 episodes of UrbanPedestrians-v0" in err
    assert cli.main(["train", *SMOKE, "--run-dir", str(tmp_path / "b")]) == 0
    err = capsys.readouterr().err
    assert "compiling" not in err and "evaluating" not in err
