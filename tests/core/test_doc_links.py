"""Relative links of the hand-written documents outside the docs site (whose links ``mkdocs build
--strict`` checks, ``tests/test_docs_site.py``) lead somewhere: the file exists and, for
``file.md#anchor``, so does the heading (GitHub's anchor rule), so moving text between documents
cannot leave a dead link."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DOCS = ["README.md", "bench/README.md", "bench/RUNS.md"]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but hyphens dropped, spaces -> hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def prose(path: Path) -> str:
    """The markdown of ``path`` without its fenced code blocks."""
    return re.sub(r"```.*?```", "", path.read_text(), flags=re.S)


def anchors(path: Path) -> set[str]:
    return {anchor(m) for m in re.findall(r"^#+ (.+)$", prose(path), re.M)}


def relative_links(path: Path) -> list[str]:
    return [t for t in LINK.findall(prose(path)) if not re.match(r"[a-z]+:", t)]


def test_anchor_follows_github():
    assert anchor("Reproducing the paper's tables") == "reproducing-the-papers-tables"
    assert anchor("The `standard` preset: the real scenes trained longer") == (
        "the-standard-preset-the-real-scenes-trained-longer"
    )
    assert anchor("Rasterizer speed and memory (CPU)") == "rasterizer-speed-and-memory-cpu"


@pytest.mark.parametrize("doc", DOCS)
def test_relative_links_resolve(doc):
    source = REPO / doc
    dead = []
    for target in relative_links(source):
        file, _, fragment = target.partition("#")
        path = (source.parent / file).resolve() if file else source
        if not path.exists():
            dead.append(f"{target}: no file {path}")
        elif fragment and path.suffix == ".md" and fragment not in anchors(path):
            dead.append(f"{target}: no heading with anchor #{fragment} in {path.name}")
    assert not dead, f"{doc}: " + "; ".join(dead)
