"""A tiny trained MoE-GS model for the export and viewer tests, made with the command line on the generated
``synthetic:dnerf_like`` scene: two experts trained 20 iterations without their static warm-up (so their
Gaussians move with time), then ``moegs route --runs`` trains a router over them for 10 iterations."""

from __future__ import annotations

from pathlib import Path

import pytest

from moegs.cli import main


@pytest.fixture(scope="session")
def tiny_route(tmp_path_factory) -> Path:
    """The route folder: ``deformable/``, ``grid4d/`` (finished expert runs) and ``router_vapr/``."""
    out = tmp_path_factory.mktemp("tiny_route")
    for expert in ("deformable", "grid4d"):
        argv = ["train", "--expert", expert, "--scene", "synthetic:dnerf_like", "--iterations", "20"]
        assert main([*argv, "--set", "warm_up=0", "--out", str(out / expert), "--quiet"]) == 0
    runs = [str(out / "deformable"), str(out / "grid4d")]
    argv = ["route", "--runs", *runs, "--iterations", "10", "--gate-views", "0", "--out", str(out), "--quiet"]
    assert main(argv) == 0
    return out
