"""Which source a task depends on: a static import graph of ``moegs`` and ``bench``.

A task's code version hashes the ``moegs`` modules its work can import and, of the harness, the modules
that compute a cell's numbers (``HARNESS_HASHED``: the worker, the cell kinds and the schedule
stretching), so editing one expert or one loader invalidates the cells that use it and no others. The
other harness modules plan, store and report; what of them reaches a cell (the preset, the task's
parameters and scene) is in the task's key by value. The modules are the transitive closure,
over every ``import`` statement in a module (top level or inside functions), of:

* ``bench.worker`` and the task kind's ``bench.cells`` module (the code that runs the task; a string
  constant naming a library module, ``"moegs.moe:train_router"``, counts as an import of it),
* the module of every expert the task names (``moegs.experts`` finds experts by name, not by import;
  library code that asks the registry for a built-in expert by a literal name imports that expert),
* the loader module of the task's dataset (``moegs.data`` finds loaders by name, likewise).

Importing ``a.b.c`` runs ``a/__init__`` and ``a/b/__init__``, so parent packages are in the closure
too; the C kernel's sources count when ``moegs.kernels`` is in it. Plugin experts live outside the
repository: a task naming one depends on the whole library plus the plugin's source (``code_version``).
"""

from __future__ import annotations

import ast
import hashlib
import os
import re
import sys
from collections.abc import Iterable
from functools import cache
from pathlib import Path

from bench.keys import CODE_VERSION_ENV, REPO, code_version, source_fingerprint

PACKAGES = ("moegs", "bench")
#: harness modules (and their submodules) whose code is hashed with the library's
HARNESS_HASHED = ("bench.worker", "bench.cells", "bench.schedules")
KERNEL_PACKAGE = "moegs.kernels"
#: name experts and loaders by string for every task; a task depends on those it names (task_modules)
EXPERT_REGISTRY = "moegs.experts"
REGISTRIES = (EXPERT_REGISTRY, "moegs.data")
_TARGET = re.compile(r"moegs(\.[A-Za-z_]\w*)*(:[A-Za-z_]\w*)?")
_KERNEL_SUFFIXES = (".c", ".h")


def module_file(name: str, root: Path = REPO) -> Path | None:
    """The source file of module ``name`` under ``root`` (package ``__init__.py`` or ``.py``), or None."""
    path = root.joinpath(*name.split("."))
    if (path / "__init__.py").is_file():
        return path / "__init__.py"
    if path.with_suffix(".py").is_file():
        return path.with_suffix(".py")
    return None


def _imported_names(name: str, path: Path, experts: dict[str, str]) -> set[str]:
    """Every dotted name module ``name`` may import (absolute): its import statements, library names
    spelled as strings (``"moegs.moe:train_router"``) and, where it uses the expert registry, the
    modules of the built-in experts it names (``get_expert_class("fourdgs")``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    names: set[str] = set()
    strings: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parts, base] if base else parts)
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)  # ``from pkg import module``
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            strings.add(node.value)
    if name not in REGISTRIES:
        names.update(s.partition(":")[0] for s in strings if _TARGET.fullmatch(s))
        if EXPERT_REGISTRY in names and name.split(".")[0] == "moegs":  # the harness names experts in params
            names.update(experts[s] for s in strings & experts.keys())
    return names


def builtin_experts() -> tuple[tuple[str, str], ...]:
    """``((name, module), ...)`` of the built-in experts (the registry, read without importing them)."""
    from moegs.experts import list_experts

    return tuple((s.name, s.target.partition(":")[0]) for s in list_experts() if s.plugin is None)


@cache
def import_graph(
    root: Path = REPO, experts: tuple[tuple[str, str], ...] | None = None
) -> dict[str, frozenset[str]]:
    """``{module: modules of PACKAGES it imports}`` for every module under ``root``'s PACKAGES;
    ``experts``: the built-in experts' modules by name (default: the registry's)."""
    named = dict(builtin_experts() if experts is None else experts)
    graph = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            rel = path.relative_to(root).with_suffix("")
            name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
            found = {n for n in _imported_names(name, path, named) if n.split(".")[0] in PACKAGES}
            graph[name] = frozenset(n for n in found if module_file(n, root) is not None)
    return graph


def closure(entries: Iterable[str], root: Path = REPO) -> frozenset[str]:
    """``entries``, their parent packages and everything they import, transitively."""
    graph = import_graph(root)
    seen: set[str] = set()
    todo = list(entries)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        if name not in graph:
            raise KeyError(f"no module {name!r} under {root} (looked for its .py or package __init__.py)")
        seen.add(name)
        parts = name.split(".")
        todo.extend(".".join(parts[:i]) for i in range(1, len(parts)))
        todo.extend(graph[name])
    return frozenset(seen)


def is_hashed(name: str) -> bool:
    """Whether module ``name`` counts in a task's code version: a library module or a ``HARNESS_HASHED``
    one."""
    return name.split(".")[0] == "moegs" or any(name == h or name.startswith(h + ".") for h in HARNESS_HASHED)


@cache
def source_version(modules: frozenset[str], root: Path = REPO) -> str:
    """Hash of the hashed modules (``is_hashed``) among ``modules``, and of the C kernel when
    ``moegs.kernels`` is one of them."""
    chosen = sorted(m for m in modules if is_hashed(m))
    h = hashlib.sha256()
    for name in chosen:
        path = module_file(name, root)
        h.update(str(path.relative_to(root)).encode() + b"\0" + source_fingerprint(path) + b"\0")
    if KERNEL_PACKAGE in chosen:
        kernel = root.joinpath(*KERNEL_PACKAGE.split("."))
        for path in sorted(p for p in kernel.iterdir() if p.suffix in _KERNEL_SUFFIXES):
            h.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()[:16]


@cache
def task_modules(kind: str, experts: frozenset[str], dataset: str) -> frozenset[str] | None:
    """The modules a task of cell ``kind`` naming ``experts`` on ``dataset`` can import; None when it
    names a plugin expert (outside the repository)."""
    from moegs.data import dataset_module
    from moegs.experts import get_spec

    entries = ["bench.worker", f"bench.cells.{kind}", dataset_module(dataset)]
    for name in sorted(experts):
        spec = get_spec(name)
        if spec.plugin is not None:
            return None
        entries.append(spec.target.partition(":")[0])
    return closure(entries)


def task_code_version(kind: str, experts: frozenset[str], dataset: str) -> str:
    """Hash of the library source of ``task_modules``; the whole library's ``code_version`` for a task
    naming a plugin expert; ``$MOEGS_BENCH_CODE_VERSION`` when that pins every version."""
    pinned = os.environ.get(CODE_VERSION_ENV)
    if pinned:
        return pinned
    modules = task_modules(kind, experts, dataset)
    return code_version() if modules is None else source_version(modules)


def loaded_modules() -> list[str]:
    """The library modules this process has imported, sorted: what the tasks it ran actually used."""
    graph = import_graph()
    return sorted(name for name in sys.modules if name.split(".")[0] == "moegs" and name in graph)
