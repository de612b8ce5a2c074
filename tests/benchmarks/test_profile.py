"""``benchmarks/profile.py`` on a small env run: the ops of the compiled program,
with shapes, JAX origins and times (checked for their form, not their values)."""

from __future__ import annotations

import pytest

from benchmarks import profile


def test_profile_names_the_ops_of_the_program(tmp_path):
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
