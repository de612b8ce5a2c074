"""Studies: rows pooled over seeds with intervals, curves over seeds, the command."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from drqn_jax import cli
from drqn_jax.config import ConfigError, load_config
from drqn_jax.experiments.curves import CURVES, load_curves
from drqn_jax.experiments.frontier import t_interval
from drqn_jax.experiments.machine import NOT_RECORDED, device_identity, git_commit
from drqn_jax.experiments.report import study_table
from drqn_jax.experiments.rows import baseline_row, paper_rows, study_row
from drqn_jax.experiments.study import plan_study
from drqn_jax.experiments.sweep_outputs import agent_dir, metrics_path
from tests.helpers import SMOKE_SWEEP_SET


def _run(rate: float, n: int = 100, distance: float = 100.0, free_distance: float = 120.0):
    return {
        "agent": "drqn",
        "num_episodes": n,
        "collision_free_rate": rate,
        "collision_free_ci": [rate - 0.05, rate + 0.05],
        "avg_speed_kmh": 10.0 * rate,
        "avg_speed_authors_kmh": 12.0 * rate,
        "struck_while_stopped_rate": 1.0 - rate,
        "teacher": "imitation",
        "avg_distance_m": distance,
        "avg_distance_collision_free_m": free_distance,
        "goal_rate": rate / 2,
    }


def test_paper_rows_show_the_interval_of_ten_episodes():
    """4 and 7 collision-free episodes of 10: Wilson 95 % intervals that overlap."""
    rule_based, drqn = paper_rows()
    assert rule_based["collision_free_rate"] == 0.4 and drqn["collision_free_rate"] == 0.7
    assert rule_based["collision_free_ci"] == pytest.approx((0.1682, 0.6873), abs=1e-4)
    assert drqn["collision_free_ci"] == pytest.approx((0.3968, 0.8922), abs=1e-4)
    assert drqn["collision_free_ci"][0] < rule_based["collision_free_ci"][1]


def test_a_row_pools_seeds():
    runs = [_run(0.9, distance=100.0, free_distance=110.0), _run(0.8, distance=110.0)]
    runs.append(_run(0.7, distance=120.0, free_distance=130.0))
    runs = [{**run, "env_steps": steps} for run, steps in zip(runs, (1e6, 2e6, 4.5e6), strict=True)]
    row = study_row("drqn_jax: x", "drqn", runs, world="W", decision_steps=2)
    assert row["seeds"] == 3 and row["episodes"] == 100
    assert row["env_steps_per_seed"] == pytest.approx(2.5e6)
    assert row["decision_steps"] == 2 and row["ticks_per_seed"] == pytest.approx(5e6)
    assert "| drqn_jax: x | drqn | 3 × 100 | 2 | 2.50M | 5.00M |" in study_table([row])
    assert row["collision_free_rate"] == pytest.approx(0.8)
    low, high = t_interval(np.array([0.9, 0.8, 0.7]))
    assert high > 1.0  # three seeds: a wide interval, cut at 100 %
    assert row["collision_free_ci"] == pytest.approx((low, 1.0))
    assert row["interval"] == "t over seeds"
    assert row["avg_speed_kmh"] == pytest.approx(8.0)
    assert row["avg_speed_kmh_std"] == pytest.approx(1.0)
    # all collisions (10 + 20 + 30) over all distance (33 km)
    assert row["collisions_per_km"] == pytest.approx(60 / 33.0)
    # collision-free distance weighted by collision-free episodes (90, 80, 70)
    expected = (90 * 110.0 + 80 * 120.0 + 70 * 130.0) / 240
    assert row["avg_distance_collision_free_m"] == pytest.approx(expected)


def test_a_row_says_where_and_how_long_its_seeds_trained():
    """Seeds of one study may train on several machines, some without a wall time or a
    device in their record: the device column counts each device's seeds, the wall time
    is the mean over the seeds that counted theirs, and says how many did."""
    runs = [
        {**_run(0.9), "env_steps": 10, "trained_on": "CPU A", "train_wall_s": 60.0},
        {**_run(0.8), "env_steps": 10, "trained_on": "GPU B", "train_wall_s": 180.0},
        {**_run(0.7), "env_steps": 10, "trained_on": "CPU A"},
        {**_run(0.6), "env_steps": 10},  # its device not recorded
    ]
    row = study_row("drqn_jax: x", "drqn", runs, world="W")
    assert row["devices"] == {"CPU A": 2, "GPU B": 1, NOT_RECORDED: 1}
    assert row["train_wall_s_per_seed"] == 120.0 and row["train_wall_seeds"] == 2
    table = study_table([row, baseline_row("rule-based", _run(0.5), world="W")])
    assert "| 4 × 100 | – | 0.00M | – | 2.0 (2 of 4) | [1] ×2, [2] ×1, ? ×1 |" in table
    training = table[table.index("Training:") :]
    assert "| rule-based |" in table and "| rule-based |" not in training  # not trained here
    assert "Devices: [1] CPU A; [2] GPU B." in table
    every = [{**r, "train_wall_s": 60.0} for r in runs]
    assert "| 0.00M | – | 1.0 | [1] ×2" in study_table([study_row("y", "drqn", every, world="W")])


def test_a_single_policy_keeps_its_wilson_interval():
    row = baseline_row("drqn_jax: env", _run(0.95), world="W")
    assert row["collision_free_ci"] == pytest.approx((0.9, 1.0))
    assert row["interval"] == "Wilson over episodes" and math.isnan(row["avg_speed_kmh_std"])
    table = study_table([*paper_rows(), row])
    paper = "| paper (CARLA) | rule-based | – (not learned) | 1 × 10 | 40.0 (16.8–68.7) | – |"
    assert paper + " – | 7.79 |" in table
    assert "| paper (CARLA) | rule-based | – | 82.6 | – | – | – |" in table  # driving
    ours = "| drqn_jax: env | drqn | imitation | 1 × 100 | 95.0 (90.0–100.0) | – | 5.0 |"
    assert ours + " 9.50 |" in table and "| drqn_jax: env | drqn | 11.40 | 100.0 |" in table
    # a result without the struck-while-stopped rate: – in its cell
    unstruck = {k: v for k, v in _run(0.95).items() if k != "struck_while_stopped_rate"}
    assert "| 95.0 (90.0–100.0) | – | – | 9.50 |" in study_table(
        [baseline_row("unstruck", unstruck, world="W")]
    )
    assert row["per_seed"] == [
        {"seed": None, "collision_free_rate": 0.95, "avg_speed_kmh": pytest.approx(9.5)}
    ]


def _write_metrics(path, returns, lengths):
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = ["episode,episode_return,length"]
    lines += [f"{i},{r},{n}" for i, (r, n) in enumerate(zip(returns, lengths, strict=True))]
    path.write_text("\n".join(lines) + "\n")


def test_a_report_only_run_keeps_the_provenance_of_the_runs(study):
    """--report-only rewrites a section's rows, but its command and wall time stay
    those of the study that trained the runs (the report command is added)."""
    path = study.parent / "results.json"
    before = json.loads(path.read_text())["sections"]["table"]
    argv = ["study", *STUDY, "--out", str(study), "--no-png", "--report-only"]
    assert cli.main([*argv, "--results", str(path), "--section", "table"]) == 0
    after = json.loads(path.read_text())["sections"]["table"]
    assert (after["command"], after["wall_time_s"]) == (before["command"], before["wall_time_s"])
    assert "--report-only" in after["report_command"]
    # a section an earlier report wrote takes the later report's command
    fresh = study.parent / "fresh.json"
    assert cli.main([*argv, "--results", str(fresh), "--section", "table"]) == 0
    first = json.loads(fresh.read_text())["sections"]["table"]["command"]
    assert cli.main([*argv, "--smooth", "3", "--results", str(fresh), "--section", "table"]) == 0
    later = json.loads(fresh.read_text())["sections"]["table"]
    assert "--smooth 3" in later["command"] and "--smooth 3" not in first
    assert "report_command" not in later


def test_a_study_that_goes_on_from_earlier_runs_says_so_beside_its_wall_time(study):
    """The wall time of a study continued from checkpoints or finished runs covers
    only its last invocation: the stored section says so (``continued``)."""
    assert (
        json.loads((study.parent / "results.json").read_text())["sections"]["table"]["continued"]
        is False
    )
    path = study.parent / "again.json"
    argv = ["study", *STUDY, "--out", str(study), "--no-png", "--results", str(path)]
    assert cli.main([*argv, "--section", "again"]) == 0  # every run already finished
    about = json.loads(path.read_text())["sections"]["again"]
    assert about["continued"] is True


def test_curves_are_running_means_against_env_steps_over_the_episodes_all_seeds_recorded(
    tmp_path,
):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    _write_metrics(a, [1.0, 3.0, 5.0, 7.0], [10, 20, 30, 40])
    _write_metrics(b, [3.0, 5.0, 7.0], [30, 30, 30])
    curves = load_curves([a, b], smooth=2)
    assert set(curves) == {column for column, _ in CURVES}
    ret = curves["episode_return"]
    np.testing.assert_array_equal(ret.seeds, [[1.0, 3.0, 5.0], [3.0, 5.0, 7.0]])
    # episodes end at env steps a → 10, 30, 60; b → 30, 60, 90: the grid ends at 60
    np.testing.assert_array_equal(ret.seed_steps, [[10, 30, 60], [30, 60, 90]])
    assert ret.env_steps[0] == 0.0 and ret.env_steps[-1] == 60.0
    # running means of 2: a → 1, 2, 4 and b → 3, 4, 6, linear between the episode ends
    seed_a = np.interp(ret.env_steps, [10, 30, 60], [1.0, 2.0, 4.0])
    seed_b = np.interp(ret.env_steps, [30, 60, 90], [3.0, 4.0, 6.0])
    np.testing.assert_allclose(ret.mean, (seed_a + seed_b) / 2)
    np.testing.assert_allclose(ret.low, np.minimum(seed_a, seed_b))
    np.testing.assert_allclose(ret.high, np.maximum(seed_a, seed_b))
    np.testing.assert_allclose([ret.low[-1], ret.high[-1]], [4.0, 4.0])  # both at 60 steps
    with pytest.raises(ValueError, match="no training metrics"):
        load_curves([a, tmp_path / "missing.csv"])


def test_a_study_is_validated_before_anything_runs():
    with pytest.raises(ConfigError, match="--seeds 0"):
        plan_study(["smoke"], 0, 10)
    with pytest.raises(ConfigError, match="share a name"):
        plan_study(["smoke", "configs/smoke.toml"], 2, 10)
    with pytest.raises(ConfigError, match=r"train\.gamma"):
        plan_study(["smoke"], 2, 10, ["train.gamma=2.0"])


#: test_sweep's sweep settings and its evaluation (2 episodes), so that the
#: persistent compilation cache serves its programs to whichever file runs later.
EPISODES = 2
STUDY = ["--configs", "smoke", "--seeds", "2", "--episodes", str(EPISODES), "--quiet"]
STUDY += [arg for setting in SMOKE_SWEEP_SET for arg in ("--set", setting)]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """The smoke study, 2 seeds; ``HEAD`` "moves" after the sweep first reads it (a
    checkout edited while a long study trains): each run records the commit it started
    at."""
    import drqn_jax.experiments.sweep_runner as sweep_runner

    out = tmp_path_factory.mktemp("study") / "out"
    results = ["--results", str(out.parent / "results.json"), "--section", "table"]
    heads = iter([git_commit()])
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sweep_runner, "git_commit", lambda: next(heads, "HEAD moved"))
        assert cli.main(["study", *STUDY, "--out", str(out), *results]) == 0
    return out


def test_the_study_stores_its_rows_in_the_results_file(study):
    """docs/results.json's rows come from the study command, with the world,
    whether a teacher was used, and the command that reproduces them."""
    record = json.loads((study.parent / "results.json").read_text())
    table = json.loads((study / "study.json").read_text())
    assert [r["section"] for r in record["rows"]] == ["table"] * len(table["rows"])
    assert [{k: v for k, v in r.items() if k != "section"} for r in record["rows"]] == table["rows"]
    worlds = {(r["agent"], r["world"], r["teacher"]) for r in record["rows"]}
    assert ("rule-based", "UrbanPedestrians-v0", False) in worlds
    assert ("drqn", "UrbanPedestrians-v0", False) in worlds
    about = record["sections"]["table"]
    assert about["command"].startswith("drqn-jax study --configs smoke --seeds 2")
    assert about["wall_time_s"] > 0 and about["machine"]["jax_version"]
    assert about["comparisons"] == table["comparisons"]


def test_the_study_writes_the_table_and_the_curves(study):
    record = json.loads((study / "study.json").read_text())
    labels = [(r["label"], r["agent"]) for r in record["rows"]]
    assert labels == [
        ("paper (CARLA)", "rule-based"),
        ("paper (CARLA)", "DRQN"),
        ("drqn_jax: smoke", "drqn"),
        ("drqn_jax: UrbanPedestrians-v0", "rule-based"),
    ]
    runs = record["runs"]["smoke"]
    assert [r["values"] for r in runs] == [{"run.seed": 0}, {"run.seed": 1}]
    drqn = record["rows"][2]
    assert drqn["seeds"] == 2 and drqn["episodes"] == EPISODES
    rates = [r["collision_free_rate"] for r in runs]
    assert drqn["collision_free_rate"] == pytest.approx(np.mean(rates))
    baseline = json.loads(next((study / "baselines").glob("rule-based-*.json")).read_text())
    assert baseline["num_episodes"] == EPISODES == record["rows"][3]["episodes"]
    table = (study / "study.md").read_text()
    steps = [json.loads((agent_dir(study / "smoke", i) / "agent.json").read_text()) for i in (0, 1)]
    assert [r["env_steps"] for r in runs] == [s["env_steps"] for s in steps]  # each run's own
    assert {r["trained_on"] for r in runs} == {device_identity()}  # runs may span machines
    assert {r["commit"] for r in runs} == {git_commit()}
    assert drqn["env_steps_per_seed"] == pytest.approx(np.mean([r["env_steps"] for r in runs]))
    walls = [json.loads(p.read_text()) for p in sorted(study.glob("smoke/calls/*/timing.json"))]
    assert [w["runs"] for w in walls] == [[0], [1]] and all(w["train_wall_s"] > 0 for w in walls)
    assert drqn["train_wall_s_per_seed"] == pytest.approx(
        np.mean([w["train_wall_s"] for w in walls])
    )
    assert not any("train_wall_s" in r for r in runs)  # results only: timings differ per training
    assert drqn["devices"] == {device_identity(): 2} and record["rows"][3]["devices"] == {}
    assert drqn["decision_steps"] == 1 and drqn["ticks_per_seed"] == drqn["env_steps_per_seed"]
    millions = f"{drqn['env_steps_per_seed'] / 1e6:.2f}M"
    steps_cell = (
        f"| 2 × {EPISODES} | 1 | {millions} | {millions} "
        f"| {drqn['train_wall_s_per_seed'] / 60:.1f} | [1] ×2 |"
    )
    assert f"| drqn_jax: smoke | drqn {steps_cell}" in table
    assert f"Devices: [1] {device_identity()}." in table
    assert "* drqn_jax: smoke (drqn) at " in table
    sentences = [line[2:] for line in table.splitlines() if line[:2] == "* " and line[2] != "*"]
    assert record["comparisons"] == sentences
    assert "* **collision-free % (95 % interval)**: " in table  # the columns' legend
    assert record["comparisons"][0].startswith("The paper's claim (a DRQN safer than")  # headline
    assert (study / "curves.rrd").stat().st_size > 0
    for png in ("curves.png", "safety_speed.png"):
        assert (study / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (study.parent / "figures" / "table-safety-speed.png").is_file()  # beside --results


def test_every_row_of_our_world_has_its_margin_to_the_frontier(study):
    """SPEC §9: each trained row's margin is the mean over seeds of each seed's rate minus
    the rule-based frontier at that seed's speed (the frontier the study swept on the same
    episodes, with the planner's beside it); the paper's rows (CARLA) have none."""
    from drqn_jax.experiments.frontier import frontier_rate, frontier_vertices

    record = json.loads((study / "study.json").read_text())
    (frontier,) = record["frontiers"].values()
    assert frontier["episodes"] == EPISODES and frontier["world"] == "UrbanPedestrians-v0"
    assert len(frontier["planner"]["points"]) >= 3
    vertices = frontier_vertices(frontier["rule_based"]["points"])
    paper_a, paper_b, drqn, rule = record["rows"]
    assert paper_a.get("frontier_margin") is None and paper_b.get("frontier_margin") is None
    runs = record["runs"]["smoke"]
    margins = [r["collision_free_rate"] - frontier_rate(vertices, r["avg_speed_kmh"]) for r in runs]
    assert drqn["frontier_margin"] == pytest.approx(np.mean(margins))
    assert drqn["frontier_margin_ci"] == pytest.approx(t_interval(np.array(margins)), nan_ok=True)
    at = frontier_rate(vertices, rule["avg_speed_kmh"])
    assert rule["frontier_margin"] == pytest.approx(rule["collision_free_rate"] - at)
    assert rule["frontier_margin"] <= 1e-12  # the default setting is one of those swept
    stored = json.loads((study.parent / "results.json").read_text())["sections"]["table"]
    assert stored["frontiers"] == record["frontiers"]


def test_a_ppo_arm_is_named_by_its_learner(tmp_path):
    """A config with ``train.algorithm = "ppo"`` trains, is evaluated and gets a
    row named ``ppo``, not after its network kind."""
    config = tmp_path / "smoke-ppo.toml"
    config.write_text(
        'extends = "smoke"\n[train]\nalgorithm = "ppo"\nnum_minibatches = 2\nrollout_steps = 8\n'
    )
    out = tmp_path / "out"
    args = ["--configs", str(config), "--seeds", "1", "--episodes", "2", "--quiet"]
    assert cli.main(["study", *args, "--out", str(out)]) == 0
    rows = json.loads((out / "study.json").read_text())["rows"]
    assert ("drqn_jax: smoke-ppo", "ppo") in [(r["label"], r["agent"]) for r in rows]


def test_configs_differing_only_in_reward_share_one_rule_based_row(tmp_path):
    """The rule-based agent ignores the reward: a config that changes only the reward
    adds no second, identical rule-based row (it did in Table III's first run)."""
    config = tmp_path / "smoke-reward.toml"
    config.write_text('extends = "smoke"\n[env]\nreward_collision = -50.0\n')
    out = tmp_path / "out"
    args = ["--configs", f"smoke,{config}", "--seeds", "2", "--episodes", "2", "--quiet"]
    args += [arg for setting in SMOKE_SWEEP_SET for arg in ("--set", setting)]
    assert cli.main(["study", *args, "--out", str(out), "--no-png"]) == 0
    rows = json.loads((out / "study.json").read_text())["rows"]
    assert len(list((out / "baselines").glob("rule-based-*.json"))) == 2  # two env keys
    assert [r["agent"] for r in rows].count("rule-based") == 2  # the paper's and ours
    # the same world and episodes, so the same frontier: the arms are paired
    comparisons = json.loads((out / "study.json").read_text())["comparisons"]
    assert any(c.startswith("smoke − smoke-reward, margin to the rule-based") for c in comparisons)


def test_the_curves_are_the_logged_metrics(study):
    curves = load_curves([metrics_path(study / "smoke", i) for i in range(2)], smooth=1)
    for i in range(2):
        logged = np.loadtxt(metrics_path(study / "smoke", i), delimiter=",", skiprows=1)
        np.testing.assert_array_equal(curves["length"].seeds[i], logged[:, 2])
        np.testing.assert_array_equal(curves["length"].seed_steps[i], np.cumsum(logged[:, 2]))
    end = curves["length"].seed_steps[:, -1].min()
    assert curves["length"].env_steps[-1] == end  # the grid stops where every seed has data


def test_running_the_study_again_continues_it_without_training(study, monkeypatch):
    import drqn_jax.experiments.sweep_runner as sweep_runner

    def no_training(*args, **kwargs):
        raise AssertionError("a finished study trained again")

    monkeypatch.setattr(sweep_runner, "train_call", no_training)
    before = (study / "study.json").read_text()
    assert cli.main(["study", *STUDY, "--out", str(study), "--no-png"]) == 0
    assert (study / "study.json").read_text() == before


def test_a_report_covers_the_runs_that_have_finished(study, tmp_path, monkeypatch):
    """--report-only trains nothing; with a run's call not ended, the row has one seed."""
    import shutil

    import drqn_jax.experiments.sweep_runner as sweep_runner

    monkeypatch.setattr(sweep_runner, "run_sweep", None)  # must not be called
    partial = tmp_path / "partial"
    shutil.copytree(study, partial)
    (call,) = [p for p in (partial / "smoke" / "calls").iterdir() if "0001" in p.name]
    shutil.rmtree(call)  # on the CPU each call holds one run: run 1 has not finished
    assert cli.main(["study", *STUDY, "--out", str(partial), "--report-only"]) == 0
    record = json.loads((partial / "study.json").read_text())
    assert [r["index"] for r in record["runs"]["smoke"]] == [0]
    row = f"| drqn_jax: smoke | drqn | none (reward alone) | 1 × {EPISODES} |"
    assert row in (partial / "study.md").read_text()


def test_an_interrupted_study_keeps_its_finished_runs_in_its_runs_store(
    study, tmp_path, monkeypatch
):
    """The study's directory may be lost (a fresh clone): interrupted with --results, it
    keeps each finished run in its runs store (``finished-runs/<section>.json`` beside the results
    file, which marks the section in progress and holds no runs), and the same command
    in a fresh --out trains only the other runs, to the same rows bit for bit; finished,
    it removes the store. ``--runs-store`` names another store, with no results file."""
    import shutil

    import drqn_jax.experiments.sweep_runner as sweep_runner

    partial = tmp_path / "partial"
    shutil.copytree(study, partial)
    (call,) = [p for p in (partial / "smoke" / "calls").iterdir() if "0001" in p.name]
    shutil.rmtree(call)  # on the CPU each call holds one run: run 1 has not finished
    real, trained = sweep_runner.train_call, []
    monkeypatch.setattr(
        sweep_runner, "train_call", lambda *a, **k: sweep_runner.CallOutcome("interrupted", *a)
    )
    results, store = tmp_path / "results.json", tmp_path / "finished-runs" / "s.json"
    argv = ["study", *STUDY, "--no-png", "--results", str(results), "--section", "s"]
    assert cli.main([*argv, "--out", str(partial)]) == 130
    kept = json.loads(store.read_text())["finished_runs"]["smoke"]
    assert [r["index"] for r in kept] == [0]
    assert kept[0]["metrics_csv"] == metrics_path(study / "smoke", 0).read_text()
    assert json.loads(results.read_text())["sections"]["s"] == {
        "command": json.loads(store.read_text())["command"],
        "runs_finished": {"smoke": 1},
        "runs_store": str(store),
    }

    def counting(call, devices, **kwargs):
        trained.append([p.index for p in call.points])
        return real(call, devices, **kwargs)

    monkeypatch.setattr(sweep_runner, "train_call", counting)
    assert cli.main([*argv, "--out", str(tmp_path / "fresh")]) == 0
    assert trained == [[1]]  # run 0 came from the runs store
    assert (
        kept[0]["train_wall_s"]
        == json.loads(next(partial.glob("smoke/calls/*0000/timing.json")).read_text())[
            "train_wall_s"
        ]
    )

    def results_of(out):  # rows less the training wall time: it differs per training
        rows = json.loads((out / "study.json").read_text())["rows"]
        return [{k: v for k, v in r.items() if k != "train_wall_s_per_seed"} for r in rows]

    assert results_of(tmp_path / "fresh") == results_of(study)
    restored = next((tmp_path / "fresh").glob("smoke/calls/*0000/timing.json"))
    assert json.loads(restored.read_text()) == {
        "train_wall_s": kept[0]["train_wall_s"],
        "runs": [0],
    }
    assert not store.exists()  # finished: the rows hold its results
    assert "wall_time_s" in json.loads(results.read_text())["sections"]["s"]
    elsewhere = tmp_path / "elsewhere.json"
    stale = {**kept[0], "training_hash": "another config"}  # restored only to its own config
    elsewhere.write_text(json.dumps({"command": "x", "finished_runs": {"smoke": [stale]}}))
    trained.clear()
    alone = ["study", *STUDY, "--no-png", "--runs-store", str(elsewhere)]
    assert cli.main([*alone, "--out", str(tmp_path / "other")]) == 0
    assert trained == [[0], [1]] and not elsewhere.exists()


def _kept_when_shut_down_in_run_1(study, tmp_path, monkeypatch, edit_run_0=None):
    """The study's runs kept in its runs store when the machine goes while run 1 trains
    (no SIGTERM, no interruption); ``edit_run_0`` may rewrite run 0's record first."""
    import shutil

    import drqn_jax.experiments.sweep_runner as sweep_runner

    partial = tmp_path / "partial"
    shutil.copytree(study, partial)
    calls = sorted((partial / "smoke" / "calls").iterdir())
    shutil.rmtree(calls[1])  # run 0 has finished, run 1 is training when the machine goes
    if edit_run_0 is not None:
        saved = calls[0] / "runs.json"
        saved.write_text(json.dumps([edit_run_0(r) for r in json.loads(saved.read_text())]))

    def shut_down(*args, **kwargs):
        raise SystemExit("the machine was shut down")

    monkeypatch.setattr(sweep_runner, "train_call", shut_down)
    results = tmp_path / "results.json"
    argv = ["study", *STUDY, "--no-png", "--results", str(results), "--section", "s"]
    with pytest.raises(SystemExit, match="shut down"):
        cli.main([*argv, "--out", str(partial)])
    return json.loads((tmp_path / "finished-runs" / "s.json").read_text())["finished_runs"]["smoke"]


def test_a_study_keeps_each_finished_run_before_the_next_one_trains(study, tmp_path, monkeypatch):
    """A machine shut down without warning still leaves every run that had finished in
    the runs store: they are kept as each one ends, with the commit that trained them."""
    kept = _kept_when_shut_down_in_run_1(study, tmp_path, monkeypatch)
    assert [r["index"] for r in kept] == [0]
    assert kept[0]["commit"] == git_commit()


def test_the_estimate_is_the_runs_env_steps_over_the_timed_rate(monkeypatch):
    """Issue 53: a study's training wall time, printed before it trains: each run's env
    steps (its step budget, or at most episodes × max_steps) over the env steps per
    second of one timed chunk, times the runs."""
    from drqn_jax.commands import bench

    timed = []

    def figures(config, iterations, seeds=1):
        timed.append((iterations, seeds))
        return {"env_steps": 1000 * seeds, "seconds": 2.0, "compile_s": 9.0}

    monkeypatch.setattr(bench, "train_figures", figures)
    pqn = load_config("pqn", ["train.num_env_steps=6000000"])
    estimate = bench.training_estimate(pqn, 5)
    assert estimate["seconds"] == 5 * 6_000_000 / 500 and not estimate["upper_bound"]
    assert timed == [(pqn["train"]["chunk_iterations"], 1)]
    batched = bench.training_estimate(pqn, 5, batched=True)  # 5 runs in one program
    assert batched["seconds"] == 5 * 6_000_000 / 2500 and timed[-1][1] == 5
    paper = bench.training_estimate(load_config("paper"), 2)
    assert paper["upper_bound"] and paper["env_steps_per_run"] == 200 * 1000


def test_the_study_prints_its_estimate_and_trains_nothing(tmp_path, monkeypatch, capsys):
    from drqn_jax.commands import bench

    def estimate(config, runs, batched=False):
        if config["train"]["algorithm"] == "ppo":
            return "the run finished before learning started; raise train.num_episodes"
        seconds = 3 * 3600.0 + 25 * 60.0
        return {
            "env_steps_per_run": 180,
            "upper_bound": True,
            "env_steps_per_s": 2.5,
            "seconds": seconds,
        }

    monkeypatch.setattr(bench, "training_estimate", estimate)
    ppo = tmp_path / "smoke-ppo.toml"
    ppo.write_text('extends = "smoke"\n[train]\nalgorithm = "ppo"\nnum_minibatches = 2\n')
    out = tmp_path / "out"
    argv = ["study", "--configs", f"smoke,{ppo}", "--seeds", "3", "--estimate", "--out", str(out)]
    assert cli.main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    each = "at most 180 env steps at 2 env steps/s: at most 3 h 25 min"
    assert lines[0] == f"smoke on this cpu: 3 runs (map) × {each}"
    assert lines[1].startswith("smoke-ppo: no estimate: the run finished before learning")
    assert lines[2] == "training in all: at most 3 h 25 min (1 not estimated)"
    assert not out.exists()
    # one run (reproduce --train): no sweep and no total
    one = bench.estimate_lines([("smoke", load_config("smoke"), 1, "auto")])
    assert one == f"smoke on this cpu: {each}"


def test_eval_envs_evaluate_the_trained_agents_among_other_pedestrians(
    study, tmp_path, monkeypatch, capsys
):
    """--eval-envs on a finished study trains nothing: every run's agent among the
    realistic pedestrians, on the study's episodes, as `drqn-jax evaluate` scores it."""
    import shutil

    import drqn_jax.experiments.sweep_runner as sweep_runner

    def no_training(*args, **kwargs):
        raise AssertionError("a finished study trained again")

    monkeypatch.setattr(sweep_runner, "train_call", no_training)
    out = tmp_path / "cross"
    shutil.copytree(study, out)
    realistic = "UrbanPedestriansRealistic-v0"
    envs = ["--eval-envs", f"{realistic},UrbanPedestrians-v0"]  # its own env adds nothing
    assert cli.main(["study", *STUDY, "--out", str(out), "--no-png", *envs]) == 0
    record = json.loads((out / "study.json").read_text())
    assert [(r["label"], r["agent"]) for r in record["rows"][2:]] == [
        ("drqn_jax: smoke", "drqn"),
        (f"drqn_jax: smoke on {realistic}", "drqn"),
        ("drqn_jax: UrbanPedestrians-v0", "rule-based"),
        (f"drqn_jax: {realistic}", "rule-based"),
    ]
    assert record["comparisons"][2].startswith(f"drqn_jax: smoke on {realistic} (drqn) at ")
    assert len(record["frontiers"]) == 2  # each world's own frontier
    assert all(r["frontier_margin"] is not None for r in record["rows"][2:])
    cross = record["cross"]["smoke"][realistic]
    assert [r["index"] for r in cross] == [0, 1]
    evaluation = tmp_path / "run1.json"
    agent = str(agent_dir(out / "smoke", 1))
    command = ["evaluate", agent, "--seed", "0", "--set", f"env.id={realistic}"]
    assert cli.main([*command, "--json", str(evaluation)]) == 0
    alone = json.loads(evaluation.read_text())
    for name in ("num_episodes", "collision_free_rate", "avg_speed_kmh", "avg_distance_m"):
        assert cross[1][name] == alone[name], name
    # a study whose runs kept no agents says so
    shutil.rmtree(out / "smoke" / "cross")
    shutil.rmtree(out / "smoke" / "agents")
    capsys.readouterr()
    assert cli.main(["study", *STUDY, "--out", str(out), "--no-png", *envs]) == 2
    assert "no trained agent to evaluate" in capsys.readouterr().err


def test_eval_envs_are_validated_before_anything_runs():
    with pytest.raises(ConfigError, match="--eval-envs 'Nope-v0': must be one of"):
        plan_study(["smoke"], 2, 10, eval_envs=["Nope-v0"])
    (arm,) = plan_study(["realistic"], 2, 10, eval_envs=["UrbanPedestriansRealistic-v0"])
    assert arm.cross_envs == ()  # its own env


def test_a_runs_store_edited_apart_from_the_study_directory_is_named(
    study, tmp_path, monkeypatch, capsys
):
    """Continued in its own --out, a study keeps that directory's runs and stores them
    again: a record edited in the runs store alone would silently go back, so the
    study names the runs whose records differ."""
    kept = _kept_when_shut_down_in_run_1(study, tmp_path, monkeypatch)
    store = tmp_path / "finished-runs" / "s.json"
    argv = ["study", *STUDY, "--no-png", "--results", str(tmp_path / "results.json")]
    argv += ["--section", "s"]
    capsys.readouterr()
    with pytest.raises(SystemExit, match="shut down"):  # the same records: nothing to say
        cli.main([*argv, "--out", str(tmp_path / "partial")])
    assert "differ from the runs store" not in capsys.readouterr().err
    record = json.loads(store.read_text())
    record["finished_runs"]["smoke"][0] = {**kept[0], "final_train_return": 0.5}
    store.write_text(json.dumps(record))
    with pytest.raises(SystemExit, match="shut down"):  # run 1 still cannot train
        cli.main([*argv, "--out", str(tmp_path / "partial")])
    assert "smoke: run(s) [0] in" in capsys.readouterr().err
    again = json.loads(store.read_text())["finished_runs"]["smoke"]
    assert again == kept  # the directory's record, stored again
