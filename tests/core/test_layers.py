"""The library never imports its harness: no module under ``moegs/`` imports ``bench`` (not even lazily)."""

from __future__ import annotations

import ast
from pathlib import Path

MOEGS = Path(__file__).resolve().parents[2] / "moegs"


def imported_modules(path: Path) -> set[str]:
    """Every module an ``import`` / ``from ... import`` statement of the file names (top level or nested)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def test_moegs_never_imports_bench():
    offenders = {
        str(path.relative_to(MOEGS.parent)): sorted(
            m for m in imported_modules(path) if m.split(".")[0] == "bench"
        )
        for path in sorted(MOEGS.rglob("*.py"))
    }
    offenders = {k: v for k, v in offenders.items() if v}
    assert not offenders, f"moegs modules importing the harness: {offenders}"


def test_the_check_sees_nested_imports(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    from bench.paper import load_paper_table\n    import bench.spec\n")
    assert {"bench.paper", "bench.spec"} <= imported_modules(probe)
