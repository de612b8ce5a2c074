"""``benchmarks/suite_profile.py``: the plugin records each test's compiles, the summary
adds them up per file and per worker."""

from __future__ import annotations

import textwrap

import jax

from benchmarks.suite_profile import (
    FIELDS,
    main,
    program_tables,
    read_programs,
    read_rows,
    summary,
)

pytest_plugins = ["pytester"]


def test_the_plugin_records_each_tests_wall_time_and_compiles(pytester, monkeypatch):
    out = pytester.path / "profile"
    monkeypatch.setenv("SUITE_PROFILE_DIR", str(out))
    pytester.makepyfile(
        test_two=textwrap.dedent("""
            import jax, jax.numpy as jnp

            def tripled_sine(x):
                return jnp.sin(x) * 3.0

            def test_compiles():
                jax.jit(tripled_sine)(jnp.arange(7.0)).block_until_ready()

            def test_nothing():
                pass

            def test_compiles_it_again():
                jax.clear_caches()  # too quick for the persistent cache: compiled again
                jax.jit(tripled_sine)(jnp.arange(7.0)).block_until_ready()
        """)
    )
    # the suite keeps every compile (conftest); here a quick one must not be kept
    minimum = jax.config.jax_persistent_cache_min_compile_time_secs
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 60.0)
    try:
        result = pytester.runpytest_inprocess("-p", "benchmarks.suite_profile")
    finally:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", minimum)
    result.assert_outcomes(passed=3)
    rows = {r["test"]: r for r in read_rows(out.glob("suite-*.tsv"))}
    compiled, idle = rows["test_two.py::test_compiles"], rows["test_two.py::test_nothing"]
    assert len(rows) == 3
    assert compiled["compile_s_n"] >= 1 and compiled["compile_s"] > 0.0
    assert idle["compile_s_n"] == 0 and idle["wall_s"] >= 0.0
    assert all(isinstance(r["maps_added"], int) for r in rows.values())
    programs = read_programs(out.glob("compiles-*.tsv"))
    sines = [p for p in programs if p["program"] == "jit_tripled_sine"]
    assert [p["test"].split("::")[1] for p in sines] == ["test_compiles", "test_compiles_it_again"]
    assert sines[0]["key"] == sines[1]["key"] and sines[0]["outcome"] == "miss"
    assert all(p["compile_s"] > 0.0 for p in sines)
    repeated = {g["program"]: g for g in program_tables(programs, top=5)["repeated"]}
    sine = repeated["jit_tripled_sine"]
    assert (sine["compiles"], sine["keys"], sine["files"]) == (2, 1, "test_two.py")


def test_the_summary_adds_up_per_file_and_per_worker(tmp_path, capsys):
    def line(test: str, wall: float, compile_s: float, compiles: int, maps: int = 10) -> str:
        cells = [test, wall, 0.5, 2, 0.25, 2, compile_s, compiles, 0.0, 1, maps]
        assert len(cells) == len(FIELDS)
        return "\t".join(map(str, cells))

    (tmp_path / "suite-1.tsv").write_text(
        line("tests/a.py::t1", 10.0, 6.0, 3, 40) + "\n" + line("tests/b.py::t", 2.0, 1.0, 1) + "\n"
    )
    (tmp_path / "suite-2.tsv").write_text(line("tests/a.py::t2", 5.0, 4.0, 2) + "\n")
    (tmp_path / "suite-3.tsv").write_text("")  # the xdist controller's
    result = summary(read_rows(sorted(tmp_path.glob("suite-*.tsv"))))
    assert result["tests"] == 3
    assert result["workers"] == {"suite-1": 12.0, "suite-2": 5.0}
    first, second = result["files"]
    assert (first["file"], first["tests"], first["wall_s"]) == ("tests/a.py", 2, 15.0)
    assert (first["compile_s"], first["compile_s_n"], first["cache_hit_s_n"]) == (10.0, 5, 2)
    assert first["maps_added"] == 50 and isinstance(first["maps_added"], int)
    assert (second["file"], second["wall_s"]) == ("tests/b.py", 2.0)
    assert result["total"]["trace_s"] == 1.5
    (tmp_path / "compiles-1.tsv").write_text(
        "tests/a.py::t1\tjit_train\tk1\tmiss\t4.0\n"
        "tests/b.py::t\tjit_train\tk1\tmiss\t3.0\n"
        "tests/b.py::t\tjit_train\tk2\tmiss\t1.0\n"
        "tests/a.py::t1\tjit_step\tk3\thit\t0.0\n"
    )
    printed = main([str(tmp_path)])
    assert printed["total"]["compile_s_n"] == 6
    assert printed["repeated"] == [
        {"program": "jit_train", "compiles": 2, "hits": 0, "compile_s": 7.0, "keys": 1,
         "files": "tests/a.py, tests/b.py"}
    ]  # fmt: skip
    names = {g["program"]: g for g in printed["names"]}
    assert (names["jit_train"]["compiles"], names["jit_train"]["keys"]) == (3, 2)
    assert (names["jit_step"]["compiles"], names["jit_step"]["hits"]) == (0, 1)
    printed_text = capsys.readouterr().out
    assert "| tests/a.py | 2 | 15 | 10 | 5 | 1 | 0.5 | 2 | 50 |" in printed_text
    assert "| cache hits | memory maps added |" in printed_text
