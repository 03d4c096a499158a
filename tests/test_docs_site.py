"""The documentation site builds with ``mkdocs build --strict``: a missing page, a broken link or anchor, a
figure that is not in ``reports/`` or an API reference to a name that does not exist fails here."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def test_docs_build_strict(tmp_path):
    pytest.importorskip("mkdocs", reason="pip install -e '.[docs]' (part of '.[test]')")
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
        env={"NO_MKDOCS_2_WARNING": "1", "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)},
    )
    assert done.returncode == 0, done.stderr[-4000:]
    site = tmp_path / "site"
    assert (site / "index.html").is_file() and (site / "reports/figures/fig_gates_dnerf.png").is_file()
    reference = (site / "reference/index.html").read_text()
    assert "load_scene" in reference and "train_router" in reference


def test_every_page_is_in_the_navigation():
    yaml = pytest.importorskip("yaml")

    config = yaml.safe_load((REPO / "mkdocs.yml").read_text().replace("!!python", "python"))

    def pages(nav):
        for item in nav:
            value = next(iter(item.values())) if isinstance(item, dict) else item
            yield from pages(value) if isinstance(value, list) else [value]

    listed = set(pages(config["nav"]))
    assert listed == {p.name for p in (REPO / "docs").glob("*.md")}
