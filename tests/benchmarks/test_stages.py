"""``benchmarks/stages.py`` at ``--quick`` sizes.

It runs once per module; the test checks the shape of the results and that
every derived figure is the ratio it claims to be, not the measured values.
"""

from __future__ import annotations

import json
import math

import pytest

from benchmarks import stages


@pytest.fixture(scope="module")
def stages_result(tmp_path_factory):
    out = tmp_path_factory.mktemp("stages")
    return stages.main(["--quick", "--out", str(out)]), out


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
