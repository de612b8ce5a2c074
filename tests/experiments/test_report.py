"""The results file and the documents that quote it (issue 41): sections replace
their own rows only, blocks regenerate from the file, and drift is caught."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from drqn_jax import cli
from drqn_jax.experiments.report import (
    load_results,
    render_section,
    stale_documents,
    study_table,
    update_document,
    write_results,
)
from drqn_jax.experiments.study import baseline_row, paper_rows
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
    assert stale_documents([doc], record) == [str(doc)]
    text = update_document(doc.read_text(), record)
    assert text.startswith("intro\n<!-- results:t -->\n| source |") and text.endswith("end\n")
    assert "| ours | drqn | none (reward alone) | 1 × 1000 | – | – | – | 50.0 (47.0–53.0) |" in text
    assert "drqn-jax study --configs x" in text and "wall time 10 min on" in text
    went_on = {**record, "sections": {"t": {**record["sections"]["t"], "continued": True}}}
    assert "earlier invocations trained its runs, the wall time is the last one's):" in (
        update_document(text, went_on)
    )
    doc.write_text(text)
    assert stale_documents([doc], record) == []
    doc.write_text(text.replace("50.0 (47.0", "51.0 (47.0"))  # a retyped number
    assert stale_documents([doc], record) == [str(doc)]
    with pytest.raises(ValueError, match="section 'nope'"):
        render_section(record, "nope")


def test_an_interrupted_study_renders_its_progress_not_a_table(tmp_path):
    """A section an interrupted study left (its finished runs and its command, no rows
    yet, issue 53's multi-session CPU table) renders which runs have finished and the
    command that continues it; once the study finishes, its table."""
    path = tmp_path / "results.json"
    finished = {"pqn": [{"index": 0}, {"index": 1}], "ppo": [{"index": 0}]}
    interrupted = {"command": "drqn-jax study --configs pqn,ppo", "finished_runs": finished}
    path.write_text(json.dumps({"rows": [], "sections": {"t": interrupted}}))
    text = render_section(load_results(path), "t")
    assert text.startswith("**In progress**: no table until every run has finished.")
    assert "Runs finished so far: `pqn` 2, `ppo` 1." in text
    assert "drqn-jax study --configs pqn,ppo" in text and "| source |" not in text
    record = write_results(
        path, "t", [baseline_row("ours", policy_result(0.5), world="W")], [], ABOUT
    )
    assert render_section(record, "t").startswith("| source |")


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
    header = table.splitlines()[0]
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
    assert stale_documents(docs, record) == []
    paper_world = [r for r in record["rows"] if r["world"] == "UrbanPedestrians-v0"]
    assert any(r["agent"] == "rule-based" for r in paper_world)
    assert any(r["agent"] == "drqn" and r["teacher"] is False for r in paper_world)
    for row in record["rows"]:
        low, high = row["collision_free_ci"]
        assert 0.0 <= low <= row["collision_free_rate"] <= high <= 1.0, row["label"]
