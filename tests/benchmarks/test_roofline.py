"""``benchmarks/roofline.py`` at ``--quick`` sizes.

It runs once per module; the tests check the shape of the results and that
every derived figure is the ratio it claims to be, not the measured values.
"""

from __future__ import annotations

import pytest

from benchmarks import roofline


@pytest.fixture(scope="module")
def roofline_result():
    return roofline.main(["--quick"])


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
