"""benchmarks/gymnasium_throughput.py runs and reports its three clients (no timings asserted)."""

from __future__ import annotations

from benchmarks import gymnasium_throughput


def test_the_gymnasium_benchmark_reports_each_client(capsys):
    result = gymnasium_throughput.main(["--quick"])
    clients = [row["client"] for row in result["rows"]]
    assert clients[:2] == ["gym.make (single env)", "gym.make_vec"]
    assert all(row["steps_per_s"] > 0 for row in result["rows"])
    assert result["vector_share"] > 0
    assert "| gym.make_vec | 4 |" in capsys.readouterr().out
