"""``benchmarks/stages.py`` and ``benchmarks/roofline.py`` at ``--quick`` sizes.

Each runs once per module (about half a minute together on the 2-core CPU); the
tests check the shape of the results and that every derived figure is the
ratio it claims to be, not the measured values.
"""

from __future__ import annotations

import json
import math

import pytest

from benchmarks import roofline, stages


@pytest.fixture(scope="module")
def stages_result(tmp_path_factory):
    out = tmp_path_factory.mktemp("stages")
    return stages.main(["--quick", "--out", str(out)]), out


@pytest.fixture(scope="module")
def roofline_result():
    return roofline.main(["--quick"])


def test_stages_rows(stages_result):
    result, out = stages_result
    rows = result["rows"]
    sizes = stages.QUICK_BATCH_SIZES
    assert {(r["batch_size"], r["stage"]) for r in rows} == {
        (n, s) for n in sizes for s in stages.STAGE_NAMES
    }
    for r in rows:
        assert math.isfinite(r["env_steps_per_s"]) and r["env_steps_per_s"] > 0, r
        assert 0 < r["share_of_full_step"] < math.inf, r
        assert r["ns_per_env_step"] == pytest.approx(1e9 / r["env_steps_per_s"])
        assert r["env_steps_per_s"] == pytest.approx(r["batch_size"] * r["steps"] / r["run_s"])
        assert r["compile_s"] > 0
        assert r["steps"] == 10 and len(r["run_times_s"]) == 2
        assert r.get("output_finite", True), r
    for n in sizes:
        at_n = {r["stage"]: r for r in rows if r["batch_size"] == n}
        full = at_n[stages.FULL]["ns_per_env_step"]
        assert at_n[stages.FULL]["share_of_full_step"] == 1.0
        for r in at_n.values():
            assert r["share_of_full_step"] == pytest.approx(r["ns_per_env_step"] / full)
    saved = json.loads((out / "stages.json").read_text())
    assert saved["rows"] == json.loads(json.dumps(rows, default=str))
    md = (out / "stages.md").read_text()
    assert "| N envs | stage | compile s |" in md and "share of full step" in md


def test_roofline_machine(roofline_result):
    m = roofline_result["machine_limits"]
    assert m["fma_disabled"] is True  # import drqn_jax caps XLA:CPU at AVX
    for name in ("read_write", "write", "write_fresh", "numpy_copy"):
        assert m["bandwidth"][f"{name}_gb_per_s"] > 0, name
    assert m["matmul"], "no matmul measured"
    for name, mm in m["matmul"].items():
        assert mm["gflops_per_s"] > 0, name
        assert mm["gflops_per_s"] == pytest.approx(
            2 * mm["m"] * mm["n"] * mm["k"] / mm["run_s"] / 1e9
        )


def test_roofline_fractions(roofline_result):
    rows = roofline_result["rows"]
    assert len(rows) >= 6
    for r in rows:
        assert r["achieved"] > 0 and r["limit"] > 0, r
        assert r["fraction"] == pytest.approx(r["achieved"] / r["limit"], rel=1e-12), r
    env, update = roofline_result["env"], roofline_result["update"]
    assert env["obs_bytes_per_step"] == 45 * 30 * 4 * 4
    assert env["flops_per_step"] > 0 and env["bytes_accessed_per_step"] > 0
    assert {"flops", "bytes accessed"} <= set(env["cost_analysis"])
    assert update["counted_flops"] > 0 and update["updates_per_s"] > 0
    assert update["synthetic_replay"]


def test_roofline_targets(roofline_result):
    m, e, t = (roofline_result[k] for k in ("machine_limits", "env", "targets"))
    bound = m["bandwidth"]["write_gb_per_s"] * 1e9 / e["obs_bytes_per_step"]
    assert t["obs_write_bound_steps_per_s"] == pytest.approx(bound)
    assert t["env_target_steps_per_s"] == pytest.approx(
        min(roofline.TARGET_ENV_STEPS_PER_S, roofline.TARGET_ENV_FRACTION * bound)
    )
    assert t["env_met"] == (e["env_steps_per_s"] >= t["env_target_steps_per_s"])
    assert t["updates_met"] == (
        roofline_result["update"]["updates_per_s"] >= roofline.TARGET_UPDATES_PER_S
    )


def test_profile_names_the_ops_of_the_program(tmp_path):
    from benchmarks import profile

    result = profile.main(
        ["env", "--num-envs", "64", "--steps", "10", "--top", "5", "--out", str(tmp_path)]
    )
    ops = result["ops"]
    assert ops and result["per"] == 10 and result["wall_ms"] > 0
    # Every row is an op of the compiled program, with its shape and a JAX origin.
    assert all(r["us"] >= 0 and r["calls"] >= 1 and r["origin"] for r in ops)
    assert [r["us"] for r in ops] == sorted((r["us"] for r in ops), reverse=True)
    grids = [r for r in ops if r["shape"] == "f32[64,1350,4]"]  # the observation grids
    assert grids, [r["shape"] for r in ops]
    for r in ops:
        assert r["ms_per_step"] == pytest.approx(r["us"] / 1e3 / 10)
    assert (tmp_path / "profile.json").is_file() and (tmp_path / "profile.md").is_file()
