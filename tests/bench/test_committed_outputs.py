"""The committed outputs are those of the current code.

``reports/summary.json`` and ``reports/standard/summary.json`` record the identity of the plan they were
written from (``Plan.identity``: specs, scenes, number of cells and a digest of every cell key; each key holds
the version of the library code its cell runs). A new plan of the same specs at the same preset must give the
same identity: then a warm run of HEAD would reuse every committed cell and rewrite the same tables. A change
to code that a cell runs moves its key, and this test asks for the outputs to be regenerated. A summary
written before the identity existed is skipped, naming its commit.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.plan import make_plan
from bench.presets import get_preset
from bench.registry import get_spec

REPO = Path(__file__).resolve().parents[2]
SUMMARIES = {
    "quick": REPO / "reports" / "summary.json",
    "standard": REPO / "reports" / "standard" / "summary.json",
}


def _header(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))["header"]


@pytest.mark.parametrize("name", sorted(SUMMARIES))
def test_committed_outputs_are_those_of_the_current_code(name):
    path = SUMMARIES[name]
    header = _header(path)
    cells = header.get("cells")
    if not cells:
        pytest.skip(f"{path} predates the plan identity (written at git {header['git'].get('commit')})")
    now = make_plan([get_spec(s) for s in cells["specs"]], get_preset(header["preset"])).identity()
    if now["scenes"] != cells["scenes"]:
        pytest.skip(f"MOEGS_DATA here gives the scenes {now['scenes']}, the run had {cells['scenes']}")
    assert now == cells, (
        f"{path} comes from other code than HEAD's (git {header['git'].get('commit')}): regenerate the "
        f"outputs with python -m bench.all --preset {header['preset']}"
    )


def test_the_identity_moves_with_the_code_a_cell_runs(monkeypatch):
    plan = lambda: make_plan([get_spec("tab17")], get_preset("tiny")).identity()  # noqa: E731
    monkeypatch.setenv("MOEGS_BENCH_CODE_VERSION", "a")
    first = plan()
    assert first["specs"] == ["tab17"] and first["tasks"] > 0 and plan() == first
    monkeypatch.setenv("MOEGS_BENCH_CODE_VERSION", "b")
    assert plan()["keys_digest"] != first["keys_digest"]
