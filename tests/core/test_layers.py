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


LAYERS = (
    ("kernels", "atomic"),
    ("camera", "gaussians", "fields", "errors", "paths", "threads", "device"),
    ("render", "data", "metrics", "io"),
    (
        "train.config",
        "train.params",
        "train.schedules",
        "train.optim",
        "train.set_optim",
        "train.losses",
        "train.strategy",
        "train.sampler",
        "train.memory",
        "train.stopping",
    ),  # fmt: skip
    ("experts",),
    (
        "train.loop",
        "train.entry",
        "train.checkpoint",
        "train.evaluate",
        "train.segments",
        "train.reuse",
        "train.select",
        "recipes",
    ),
    ("moe", "mode"),
    (
        "cli",
        "cli_types",
        "compare",
        "route",
        "render_path",
        "outputs",
        "exports",
        "viewer",
        "overrides",
        "guards",
    ),
)
"""The library's layers, lowest first (docs/api.md, "Layers"): a module imports only from its own layer
or lower ones. Training is two layers: the components an expert declares (config, optimiser groups,
densification strategies, losses) sit below the experts, the loop that drives them above."""


def layer_of(module: str) -> int | None:
    """Index in ``LAYERS`` of ``moegs.<module>`` (the longest matching prefix), None for the package."""
    parts = module.split(".")
    for n in (2, 1):
        name = ".".join(parts[:n])
        for i, layer in enumerate(LAYERS):
            if name in layer:
                return i
    return None


def test_imports_only_go_down_the_layers():
    upward = []
    for path in sorted(MOEGS.rglob("*.py")):
        module = ".".join(path.relative_to(MOEGS).with_suffix("").parts).removesuffix(".__init__")
        here = layer_of(module)
        if here is None and path.name == "__init__.py":  # the package and ``moegs.train``: namespaces
            continue
        assert here is not None, f"moegs.{module} is in no layer: add it to LAYERS and docs/api.md"
        for name in imported_modules(path):
            if name.split(".")[0] == "moegs" and name != "moegs":
                there = layer_of(name.removeprefix("moegs."))
                if there is not None and there > here:
                    upward.append(f"moegs.{module} -> {name}")
    assert not upward, "imports from a higher layer:\n" + "\n".join(upward)


def test_layer_lookup():
    assert layer_of("train.config") < layer_of("experts.stg") < layer_of("train.loop") < layer_of("moe.model")
    assert layer_of("train.strategy.adc") == layer_of("train.config") and layer_of("bench") is None
