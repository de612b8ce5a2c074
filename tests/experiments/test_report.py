"""The results file and the documents that quote it: sections replace their own rows
only, blocks regenerate from the file in their form, and drift is caught."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from drqn_jax import cli
from drqn_jax.experiments.report import (
    BRIEF,
    COLUMNS,
    load_results,
    note_progress,
    render_section,
    study_table,
    update_document,
    write_results,
)
from drqn_jax.experiments.rows import baseline_row, paper_rows
from tests.helpers import judged_row, policy_result

ROOT = Path(__file__).resolve().parents[2]
ABOUT = {"command": "drqn-jax study --configs x", "wall_time_s": 600.0, "machine": {}}


def test_a_section_replaces_its_own_rows_only(tmp_path):
    path = tmp_path / "results.json"
    a = [baseline_row("a", policy_result(0.5), world="W")]
    b = [baseline_row("b", policy_result(0.6), world="W"), *paper_rows()]
    write_results(path, "one", a, ["c1"], ABOUT)
    write_results(path, "two", b, [], {**ABOUT, "command": "other"})
    write_results(path, "one", [baseline_row("a2", policy_result(0.7), world="W")], [], ABOUT)
    record = load_results(path)
    assert [(r["section"], r["label"]) for r in record["rows"]] == [
        ("two", "b"),
        ("two", "paper (CARLA)"),
        ("two", "paper (CARLA)"),
        ("one", "a2"),
    ]
    assert record["sections"]["two"]["command"] == "other"
    assert record["sections"]["one"]["comparisons"] == []
    text = path.read_text()
    assert "NaN" not in text and json.loads(text) == record  # strict JSON: NaN stored as null
    with pytest.raises(ValueError, match="--section 'a b'"):
        write_results(path, "a b", a, [], ABOUT)


def test_blocks_regenerate_from_the_file_and_drift_is_caught(tmp_path):
    path = tmp_path / "results.json"
    record = write_results(
        path, "t", [baseline_row("ours", policy_result(0.5), world="W")], [], ABOUT
    )
    doc = tmp_path / "doc.md"
    doc.write_text("intro\n<!-- results:t -->\nold numbers\n<!-- /results -->\nend\n")
    text = update_document(doc.read_text(), record)
    assert text != doc.read_text()
    assert text.startswith("intro\n<!-- results:t -->\nSafety and speed:\n\n| source |")
    assert text.endswith("end\n")
    assert "| ours | drqn | none (reward alone) | 1 × 1000 | 50.0 (47.0–53.0) | – |" in text
    assert "Training:" not in text  # a policy not trained here: nothing to show there
    assert "The columns" not in text  # defined once, in a legend block
    assert "drqn-jax study --configs x" in text and "wall time 10 min on" in text
    went_on = {**record, "sections": {"t": {**record["sections"]["t"], "continued": True}}}
    assert "earlier invocations trained its runs, the wall time is the last one's):" in (
        update_document(text, went_on)
    )
    assert update_document(text, record) == text
    retyped = text.replace("50.0 (47.0", "51.0 (47.0")  # a retyped number
    assert update_document(retyped, record) == text
    with pytest.raises(ValueError, match="section 'nope'"):
        render_section(record, "nope")


def test_an_interrupted_study_renders_its_progress_not_a_table(tmp_path):
    """A section an interrupted study marks in progress (how many runs of each arm have
    finished, its command and its runs store; no rows yet, a multi-session CPU table)
    renders that, with the command that continues it; once the study finishes, its
    table. The results file holds no runs, and a section with a table keeps it."""
    path = tmp_path / "results.json"
    command = "drqn-jax study --configs pqn,ppo"
    note_progress(path, "t", {"pqn": 2, "ppo": 1}, command, "runs/t.json")
    assert load_results(path)["sections"]["t"] == {
        "command": command,
        "runs_finished": {"pqn": 2, "ppo": 1},
        "runs_store": "runs/t.json",
    }
    text = render_section(load_results(path), "t")
    assert text.startswith("**In progress**: no table until every run has finished.")
    assert "Runs finished so far: `pqn` 2, `ppo` 1." in text and "`runs/t.json`" in text
    assert command in text and "| source |" not in text
    assert render_section(load_results(path), "t", "brief") == text
    record = write_results(
        path, "t", [baseline_row("ours", policy_result(0.5), world="W")], [], ABOUT
    )
    table = render_section(record, "t")
    assert table.startswith("Safety and speed:")
    note_progress(path, "t", {"pqn": 1}, command, "runs/t.json")  # the study runs again
    assert render_section(load_results(path), "t") == table


def test_a_block_s_form_chooses_the_tables_the_legend_or_the_headline(tmp_path):
    """No table has more than 8 columns; the legend form defines every column once,
    under the tables and the command; the safety form shows the first table alone, the
    table form the same without its verdicts; the brief form is the headline table (8
    columns), the verdicts on the paper's claim and the goal alone, and where the columns are
    defined; an unknown form is an error."""
    claim = "The paper's claim (a DRQN safer than the rule-based agent) is not shown."
    goal = "Table III at scale's goal (…) is not met by ours."
    other = "ours (drqn) at 9.00 km/h: below the rule-based frontier"
    rows = [*paper_rows(), judged_row(0.6, 6.0)]
    record = write_results(tmp_path / "r.json", "t", rows, [claim, goal, other], ABOUT)
    tables = render_section(record, "t")
    legend = render_section(record, "t", "legend")
    assert legend.startswith(tables.rstrip("\n")) and "drqn-jax study --configs x" in tables
    definitions = legend.removeprefix(tables).splitlines()
    for header in COLUMNS:
        assert sum(line.startswith(f"* **{header}**: ") for line in definitions) == 1, header
    brief = render_section(record, "t", "brief")
    header, _, *table_rows = brief.split("\n\n")[0].splitlines()
    assert header == "| " + " | ".join(BRIEF) + " |" and len(BRIEF) == 8
    assert "| d | drqn | none (reward alone) | 1 × 1000 | – | 60.0 (57.0–63.0) |" in brief
    assert len(table_rows) == len(rows)
    assert f"* {claim}\n* {goal}\n" in brief and other not in brief
    assert "drqn-jax study" not in brief and "[docs/results.md](docs/results.md)" in brief
    safety = render_section(record, "t", "safety")
    assert safety.startswith("| source |")  # one table: no caption
    assert "Safety and speed:" not in safety and "Driving:" not in safety
    assert f"* {claim}" in safety and "drqn-jax study --configs x" in safety
    table = render_section(record, "t", "table")
    assert table == safety.replace(f"* {claim}\n* {goal}\n* {other}\n\n", "")
    assert "* " not in table and "drqn-jax study --configs x" in table
    for text in (legend, brief, safety, table):
        widths = [line.count(" | ") + 1 for line in text.splitlines() if line.startswith("| ")]
        assert widths and max(widths) <= 8
    with pytest.raises(ValueError, match="the form must be one of legend, safety, table, brief"):
        update_document("<!-- results:t wide -->\n<!-- /results -->\n", record)


def test_the_report_command_fills_and_checks(tmp_path, capsys):
    path = tmp_path / "results.json"
    write_results(path, "t", [baseline_row("ours", policy_result(0.5), world="W")], [], ABOUT)
    doc = tmp_path / "doc.md"
    doc.write_text("<!-- results:t -->\n<!-- /results -->\n")
    args = ["report", str(doc), "--results", str(path)]
    assert cli.main([*args, "--check"]) == 1
    assert cli.main(args) == 0
    assert cli.main([*args, "--check"]) == 0
    assert cli.main(["report", str(doc), "--results", str(tmp_path / "none.json")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_the_table_shows_the_margin_beside_struck_while_stopped():
    table = study_table([*paper_rows(), judged_row(0.6, 6.0)])
    header = table.splitlines()[2]
    assert "| margin to the rule-based frontier, points (95 %) | struck while stopped % |" in (
        header
    )
    assert "| 60.0 (57.0–63.0) | +10.0 (+7.0 to +13.0) |" in table
    assert "| 70.0 (39.7–89.2) | – |" in table  # the paper's rows: another world


def test_the_documents_quote_the_results_file():
    """README.md and docs/results.md agree with docs/results.json, block by block
    (regenerate with: drqn-jax report README.md docs/results.md), and the file holds
    Table III's rule-based and teacher-free DRQN rows in the paper's world."""
    record = load_results(ROOT / "docs" / "results.json")
    docs = [ROOT / "README.md", ROOT / "docs" / "results.md"]
    assert all("<!-- results:" in d.read_text() for d in docs)
    assert all(update_document(d.read_text(), record) == d.read_text() for d in docs)
    assert "<!-- results:table3-cpu-k5 brief -->" in docs[0].read_text()  # the headline
    report = docs[1].read_text()
    assert report.count("* **collision-free % (95 % interval)**: ") == 1  # one legend
    for doc in docs:
        lines = doc.read_text().splitlines()
        assert max(line.count(" | ") + 1 for line in lines if line.startswith("| ")) <= 8
    assert all(
        set(about) & {"runs_finished", "finished_runs"} == set()
        for about in (record["sections"].values())
    )  # results only: no study in progress, no runs
    paper_world = [r for r in record["rows"] if r["world"] == "UrbanPedestrians-v0"]
    assert any(r["agent"] == "rule-based" for r in paper_world)
    assert any(r["agent"] == "drqn" and r["teacher"] is False for r in paper_world)
    for row in record["rows"]:
        low, high = row["collision_free_ci"]
        assert 0.0 <= low <= row["collision_free_rate"] <= high <= 1.0, row["label"]
