"""``benchmarks/suite_profile.py``: the plugin records each test's compiles, the summary
adds them up per file and per worker."""

from __future__ import annotations

import textwrap

from benchmarks.suite_profile import FIELDS, main, read_rows, summary

pytest_plugins = ["pytester"]


def test_the_plugin_records_each_tests_wall_time_and_compiles(pytester, monkeypatch):
    out = pytester.path / "profile"
    monkeypatch.setenv("SUITE_PROFILE_DIR", str(out))
    pytester.makepyfile(
        test_two=textwrap.dedent("""
            import jax, jax.numpy as jnp

            def test_compiles():
                jax.jit(lambda x: jnp.sin(x) * 3.0)(jnp.arange(7.0)).block_until_ready()

            def test_nothing():
                pass
        """)
    )
    pytester.runpytest_inprocess("-p", "benchmarks.suite_profile").assert_outcomes(passed=2)
    rows = {r["test"]: r for r in read_rows(out.glob("suite-*.tsv"))}
    assert set(rows) == {"test_two.py::test_compiles", "test_two.py::test_nothing"}
    compiled, idle = rows["test_two.py::test_compiles"], rows["test_two.py::test_nothing"]
    assert compiled["compile_s_n"] >= 1 and compiled["compile_s"] > 0.0
    assert idle["compile_s_n"] == 0 and idle["wall_s"] >= 0.0


def test_the_summary_adds_up_per_file_and_per_worker(tmp_path, capsys):
    def line(test: str, wall: float, compile_s: float, compiles: int) -> str:
        cells = [test, wall, 0.5, 2, 0.25, 2, compile_s, compiles, 0.0, 1]
        assert len(cells) == len(FIELDS)
        return "\t".join(map(str, cells))

    (tmp_path / "suite-1.tsv").write_text(
        line("tests/a.py::t1", 10.0, 6.0, 3) + "\n" + line("tests/b.py::t", 2.0, 1.0, 1) + "\n"
    )
    (tmp_path / "suite-2.tsv").write_text(line("tests/a.py::t2", 5.0, 4.0, 2) + "\n")
    (tmp_path / "suite-3.tsv").write_text("")  # the xdist controller's
    result = summary(read_rows(sorted(tmp_path.glob("suite-*.tsv"))))
    assert result["tests"] == 3
    assert result["workers"] == {"suite-1": 12.0, "suite-2": 5.0}
    first, second = result["files"]
    assert (first["file"], first["tests"], first["wall_s"]) == ("tests/a.py", 2, 15.0)
    assert (first["compile_s"], first["compile_s_n"], first["cache_hit_s_n"]) == (10.0, 5, 2)
    assert (second["file"], second["wall_s"]) == ("tests/b.py", 2.0)
    assert result["total"]["trace_s"] == 1.5
    printed = main([str(tmp_path)])
    assert printed["total"]["compile_s_n"] == 6
    assert "| tests/a.py | 2 | 15 | 10 | 5 |" in capsys.readouterr().out
