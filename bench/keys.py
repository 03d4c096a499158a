"""Content addressing: canonical JSON hashes, the library's code version and software versions.

``code_version()`` hashes the whole library's source (``moegs/**.py`` and the C kernel): the version
reports name. A task's key hashes only the part of it the task can run (``bench.codedeps``), so results
and checkpoints are reused exactly while that code is unchanged, across commits that touch only other
files. A Python file counts by its syntax tree without docstrings (``source_fingerprint``): comments,
docstrings (of attributes too) and layout never invalidate a result (the tree's printed form may change
between Python versions, and every key with it). ``MOEGS_BENCH_CODE_VERSION`` pins both (reuse old
checkpoints at your own risk).
"""

from __future__ import annotations

import ast
import hashlib
import json
import os
import platform
import subprocess
import sys
from functools import cache
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
CODE_VERSION_ENV = "MOEGS_BENCH_CODE_VERSION"
_SOURCE_SUFFIXES = (".py", ".c", ".h")


def canonical_json(obj: Any) -> str:
    """Deterministic JSON (sorted keys, no spaces, tuples as lists) for hashing."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=_default)


def _default(obj: Any) -> Any:
    if isinstance(obj, tuple | set | frozenset):
        return sorted(obj) if isinstance(obj, set | frozenset) else list(obj)
    if hasattr(obj, "items"):
        return dict(obj.items())
    raise TypeError(f"cannot hash object of type {type(obj).__name__}: {obj!r}")


def digest(obj: Any, length: int = 20) -> str:
    """Hex SHA-256 of the canonical JSON of ``obj`` (first ``length`` characters)."""
    return hashlib.sha256(canonical_json(obj).encode()).hexdigest()[:length]


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def source_fingerprint(path: Path) -> bytes:
    """What of a source file can change behaviour: a ``.py`` file's syntax tree without its bare string
    statements (docstrings of modules, classes, functions and attributes; comments and layout are not in
    the tree); any other file's bytes."""
    if path.suffix != ".py":
        return path.read_bytes()
    tree = _DropBareStrings().visit(ast.parse(path.read_bytes(), filename=str(path)))
    return ast.dump(tree).encode()


class _DropBareStrings(ast.NodeTransformer):
    """Removes every statement that is only a string literal: it documents and does nothing."""

    def visit_Expr(self, node: ast.Expr) -> ast.Expr | None:
        is_text = isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)
        return None if is_text else node


@cache
def code_version() -> str:
    """Hash of the library source (``moegs/``) and of every plugin expert's module, or
    ``$MOEGS_BENCH_CODE_VERSION``."""
    pinned = os.environ.get(CODE_VERSION_ENV)
    if pinned:
        return pinned
    h = hashlib.sha256()
    root = REPO / "moegs"
    for p in sorted(root.rglob("*")):
        if p.is_file() and p.suffix in _SOURCE_SUFFIXES and "__pycache__" not in p.parts:
            h.update(str(p.relative_to(root)).encode() + b"\0" + source_fingerprint(p) + b"\0")
    for name, source in plugin_sources():
        h.update(name.encode() + b"\0" + source + b"\0")
    return h.hexdigest()[:16]


def plugin_sources() -> list[tuple[str, bytes]]:
    """``(expert name, source of its module)`` of each plugin expert (entry points), without importing
    them: a change in a plugin invalidates the cells that use it."""
    import importlib.util

    from moegs.experts import list_experts

    out = []
    for spec in list_experts():
        if spec.plugin is None:
            continue
        module = spec.target.partition(":")[0]
        found = importlib.util.find_spec(module)
        origin = Path(found.origin) if found is not None and found.origin else None
        out.append((spec.name, origin.read_bytes() if origin is not None and origin.is_file() else b""))
    return out


@cache
def git_commit() -> dict[str, Any]:
    """``{"commit": sha or None, "dirty": bool or None}`` of the repository."""

    def git(*args: str) -> str | None:
        try:
            out = subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, timeout=10)
        except (OSError, subprocess.SubprocessError):
            return None
        return out.stdout.strip() if out.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--", "moegs")
    return {"commit": commit, "dirty": None if status is None else bool(status)}


def versions() -> dict[str, Any]:
    """Software versions recorded in every result (torch only if already imported)."""
    out: dict[str, Any] = {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "moegs_code_version": code_version(),
        "moegs_git": git_commit(),
    }
    torch = sys.modules.get("torch")
    if torch is not None:
        out["torch"] = torch.__version__
        out["torch_threads"] = torch.get_num_threads()
    try:
        import moegs

        out["moegs"] = getattr(moegs, "__version__", None)
    except ImportError:
        out["moegs"] = None
    return out
