"""MkDocs hook: the committed figures under ``reports/`` become part of the site, so pages link them as
``reports/...`` (relative to the docs root) and ``mkdocs build --strict`` checks every such link."""

from __future__ import annotations

from pathlib import Path

from mkdocs.structure.files import File

REPORTS = Path(__file__).resolve().parents[2] / "reports"
SUFFIXES = {".png", ".svg", ".jpg"}


def on_files(files, config):
    for path in sorted(REPORTS.rglob("*")):
        if path.suffix in SUFFIXES:
            uri = path.relative_to(REPORTS.parent).as_posix()
            files.append(File.generated(config, uri, abs_src_path=str(path)))
    return files
