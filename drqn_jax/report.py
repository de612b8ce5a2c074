"""One machine-readable results file, and the documents that quote it (issue 41).

A study run with ``--results docs/results.json --section NAME`` stores its table's
rows there (:func:`write_results`), beside the command that produced them, its
wall time and the machine. Documents never retype those numbers: a block ::

    <!-- results:NAME -->
    (generated: the section's table, its comparisons and its command)
    <!-- /results -->

is filled from the file by ``drqn-jax report FILE.md …`` (:func:`update_document`),
and ``drqn-jax report --check`` (and the test suite) fails when a document and the
file disagree.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drqn_jax.checkpoint import atomic_write_text

__all__ = [
    "SECTION_NAME",
    "SPEED_TOLERANCE_KMH",
    "check_section",
    "claim_verdict",
    "load_results",
    "render_section",
    "stale_documents",
    "strict_json",
    "update_document",
    "write_results",
]

#: A section's name: letters, digits, '_', '.' and '-'.
SECTION_NAME = re.compile(r"[\w.-]+")
#: A generated block of a document: its section name and its current body.
BLOCK = re.compile(
    rf"(?P<open><!-- results:(?P<section>{SECTION_NAME.pattern}) -->\n)(?P<body>.*?)"
    r"(?P<close><!-- /results -->)",
    re.S,
)


def strict_json(value: Any) -> Any:
    """``value`` with tuples as lists and non-finite floats as None (strict JSON)."""
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [strict_json(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value


def check_section(section: str) -> None:
    """ValueError unless ``section`` is a valid section name (:data:`SECTION_NAME`)."""
    if not SECTION_NAME.fullmatch(section):
        raise ValueError(f"--section {section!r}: must be letters, digits, '_', '.' or '-'")


def load_results(path: str | Path) -> dict[str, Any]:
    """The results file (``{"rows": [...], "sections": {...}}``), or an empty one."""
    path = Path(path)
    if not path.is_file():
        return {"rows": [], "sections": {}}
    return json.loads(path.read_text())


def write_results(
    path: str | Path,
    section: str,
    rows: Sequence[Mapping[str, Any]],
    comparisons: Sequence[str],
    about: Mapping[str, Any],
) -> dict[str, Any]:
    """Replace ``section``'s rows of the results file at ``path`` (other sections stay).

    Each row (:func:`drqn_jax.study.study_row`) gains ``"section"``; ``about`` (the
    command, its wall time, the machine) and ``comparisons`` are stored under
    ``sections[section]``. Returns the whole record written.
    """
    check_section(section)
    record = load_results(path)
    kept = [r for r in record["rows"] if r.get("section") != section]
    record["rows"] = kept + [{"section": section, **r} for r in rows]
    record["sections"][section] = {**about, "comparisons": list(comparisons)}
    record = strict_json(record)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(Path(path), json.dumps(record, indent=1) + "\n")
    return record


def _nan(row: Mapping[str, Any]) -> dict[str, Any]:
    """A stored row with None (JSON's stand-in) back as NaN for the table."""
    return {k: math.nan if v is None else v for k, v in row.items()}


def render_section(record: Mapping[str, Any], section: str) -> str:
    """Markdown of one section: its table, its comparisons and the command beside them."""
    from drqn_jax.study import study_table

    if section not in record["sections"]:
        known = ", ".join(record["sections"]) or "none"
        raise ValueError(f"results section {section!r}: not in the results file (has: {known})")
    about = record["sections"][section]
    rows = [_nan(r) for r in record["rows"] if r.get("section") == section]
    lines = [study_table(rows), ""]
    lines += [f"* {c}" for c in about.get("comparisons", [])]
    machine = about.get("machine", {})
    went_on = (
        "; earlier invocations trained its runs, the wall time is the last one's"
        if about.get("continued")
        else ""
    )
    lines += [
        "",
        f"Command (wall time {about['wall_time_s'] / 60:.0f} min on {machine.get('usable_cores')} "
        f"cores of {machine.get('cpu_model')}, JAX {machine.get('jax_version')}, "
        f"commit {machine.get('git_commit')}{went_on}):",
        "",
        "```bash",
        about["command"],
        "```",
    ]
    return "\n".join(lines) + "\n"


def update_document(text: str, record: Mapping[str, Any]) -> str:
    """``text`` with every ``results:NAME`` block regenerated from ``record``."""

    def filled(match: re.Match[str]) -> str:
        body = render_section(record, match["section"])
        return match["open"] + body + match["close"]

    return BLOCK.sub(filled, text)


def stale_documents(paths: Sequence[str | Path], record: Mapping[str, Any]) -> list[str]:
    """The documents among ``paths`` whose blocks differ from ``record``'s numbers."""
    return [
        str(p) for p in paths if update_document(Path(p).read_text(), record) != Path(p).read_text()
    ]


#: How much slower than the rule-based agent (km/h, average speed) a DRQN may drive and
#: still count as supporting the paper's claim (issue 41's goal; the paper's DRQN
#: drove 1.7 km/h below its rule-based agent).
SPEED_TOLERANCE_KMH = 1.0


def claim_verdict(drqn: Mapping[str, Any], rule_based: Mapping[str, Any]) -> str:
    """One line on the paper's claim (Table III: the DRQN is safer than the rule-based
    agent) from two rows of the same world. Supported only where the DRQN's
    collision-free interval lies above the rule-based agent's *and* its average speed
    is no more than :data:`SPEED_TOLERANCE_KMH` below: a car that does not drive
    avoids every collision the authors' test counts."""
    (low, high), (b_low, b_high) = drqn["collision_free_ci"], rule_based["collision_free_ci"]
    gap = drqn["avg_speed_kmh"] - rule_based["avg_speed_kmh"]
    slow = gap < -SPEED_TOLERANCE_KMH
    if low > b_high and not slow:
        verdict = "supported: the DRQN's collision-free interval lies above the rule-based agent's"
    elif low > b_high:
        verdict = (
            "not shown: the DRQN's collision-free interval lies above the rule-based agent's, "
            f"but it drives more than {SPEED_TOLERANCE_KMH:g} km/h slower"
        )
    elif high < b_low:
        verdict = "reversed: the DRQN's collision-free interval lies below the rule-based agent's"
    else:
        verdict = "not shown: the collision-free intervals overlap (not distinguishable)"
    return (
        f"The paper's claim (DRQN safer than the rule-based agent) is {verdict} "
        f"({100 * low:.1f}–{100 * high:.1f} % against {100 * b_low:.1f}–{100 * b_high:.1f} %; "
        f"the DRQN's average speed is {abs(gap):.2f} km/h {'below' if gap < 0 else 'above'} "
        "the rule-based agent's)."
    )
