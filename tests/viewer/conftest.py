"""A tiny trained MoE-GS model for the export and viewer tests: ``moegs route`` on the generated
``synthetic:dnerf_like`` scene (two experts at 20 iterations, a router at 10; about 40 s on two cores)."""

from __future__ import annotations

from pathlib import Path

import pytest

from moegs.cli import main


@pytest.fixture(scope="session")
def tiny_route(tmp_path_factory) -> Path:
    """The route folder: ``deformable/``, ``grid4d/`` (finished expert runs) and ``router_vapr/``."""
    out = tmp_path_factory.mktemp("tiny_route")
    argv = ["route", "--experts", "deformable,grid4d", "--scene", "synthetic:dnerf_like", "--out", str(out)]
    argv += ["--expert-iterations", "20", "--iterations", "10", "--gate-views", "0", "--quiet"]
    assert main(argv) == 0
    return out
