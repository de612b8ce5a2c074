"""``benchmarks/peers.py``: ours vs highway-env, at smoke-run sizes.

Ours runs everywhere; highway-env only where it is installed
(``pip install -e ".[bench]"``), otherwise the run uses ``--no-highway``.
"""

from __future__ import annotations

import importlib.util
import json
import sys

import pytest

from benchmarks import peers

HAVE_HIGHWAY = importlib.util.find_spec("highway_env") is not None


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """One ``--quick`` run (with highway-env when it is importable) and its output folder."""
    out = tmp_path_factory.mktemp("peers")
    argv = ["--quick", "--out", str(out)] + ([] if HAVE_HIGHWAY else ["--no-highway"])
    return peers.main(argv), out


def test_ours(quick):
    result, out = quick
    ours = result["implementations"]["ours"]
    assert ours["available"] and ours["steps_per_s"] > 0
    assert ours["sim_s_per_wall_s"] == pytest.approx(ours["steps_per_s"] * ours["seconds_per_step"])
    assert ours["num_envs"] == peers.QUICK["num_envs"]
    assert ours["seconds_per_step"] == pytest.approx(0.1)
    assert ours["grid_finite"]
    assert json.loads((out / "peers.json").read_text())["ratios"] == result["ratios"]
    md = (out / "peers.md").read_text()
    assert "| implementation | what a step is | steps/s |" in md
    assert "ours >= 10,000 × highway-env" in md


def test_highway(quick):
    pytest.importorskip("highway_env")
    result, _ = quick
    impls = result["implementations"]
    hw = impls["highway-env"]
    assert hw["available"], hw.get("reason")
    assert hw["steps_per_s"] > 0
    assert hw["observation_shape"] == [4, 45, 30]
    assert hw["seconds_per_step"] == pytest.approx(1.0 / hw["policy_frequency_hz"])
    ratio = result["ratios"]["highway-env"]
    assert ratio["per_step"] == pytest.approx(impls["ours"]["steps_per_s"] / hw["steps_per_s"])
    assert ratio["per_simulated_s"] == pytest.approx(
        impls["ours"]["sim_s_per_wall_s"] / hw["sim_s_per_wall_s"]
    )
    target = next(t for t in result["targets"] if t["peer"] == "highway-env")
    assert target["met"] == (ratio["per_step"] >= peers.TARGET_VS_HIGHWAY)


def test_highway_unavailable(monkeypatch):
    """Without highway-env the entry says why and how to install it; targets say unmeasured."""
    monkeypatch.setitem(sys.modules, "highway_env", None)  # import raises ImportError
    hw = peers.bench_highway(num_steps=1, repeats=1, seed=0)
    assert not hw["available"]
    assert peers.INSTALL_HINT in hw["reason"]
    lines = peers.target_lines(peers.targets({"highway-env": hw}, {}))
    assert "not measured" in lines[0] and peers.INSTALL_HINT in lines[0]
    measured = {"highway-env": {"per_step": 2e4, "per_simulated_s": 2e3}}
    assert "(met)" in peers.target_lines(peers.targets({"highway-env": hw}, measured))[0]
    rows = peers.table_rows({"highway-env": hw}, {})
    assert rows[0]["steps_per_s"] == "unavailable"
