"""Cell kinds: the only code of the harness that calls the library.

One module per kind. Each module imports ``moegs`` lazily (inside functions) and provides:

* ``missing(params) -> list[str]``: library pieces the kind needs that are absent (``[]`` = runnable).
  Checked before anything runs; a cell with missing pieces is reported as
  ``"not implemented yet: <pieces>"`` and never produces a number.
* ``artifacts(task) -> list[Task]``: build tasks whose artefacts an evaluation loads.
* ``deps(task) -> list[Task]``: (build kinds) build tasks a build needs first.
* ``build(task, ctx, out_dir) -> dict``: (build kinds) write the artefact into ``out_dir``; returns meta.
* ``run(task, ctx) -> dict``: (eval kinds) ``{"metrics", "per_view", "details", "files"}``.

Kinds that never compute: ``external`` (methods outside the suite: paper value only) and
``qualitative`` (Table I).
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from functools import cache
from types import ModuleType

#: kind -> module (None: nothing to compute)
KINDS: dict[str, str | None] = {
    "scene": "bench.cells.scene",
    "expert": "bench.cells.expert",
    "moe": "bench.cells.moe",
    "mode": "bench.cells.mode",
    "distill": "bench.cells.distill",
    "trajectory": "bench.cells.trajectory",
    "bestmap": "bench.cells.bestmap",
    "gates": "bench.cells.gates",
    "mdc": "bench.cells.mdc",
    "external": None,
    "qualitative": None,
}
NOT_COMPUTED = {
    "external": "external method (paper value only)",
    "qualitative": "qualitative (nothing to compute)",
}


def kind_module(kind: str) -> ModuleType:
    """The module implementing ``kind``; ``KeyError`` lists the valid kinds."""
    if kind not in KINDS:
        raise KeyError(f"unknown cell kind {kind!r}; valid kinds: {', '.join(KINDS)}")
    target = KINDS[kind]
    if target is None:
        raise KeyError(f"cell kind {kind!r} computes nothing ({NOT_COMPUTED[kind]})")
    return importlib.import_module(target)


# ------------------------------------------------------------------ availability of library pieces
@cache
def module_missing(target: str) -> str | None:
    """``"pkg.mod"`` or ``"pkg.mod:attr"`` -> None when present, else the missing piece's name.

    The module file is located without importing it; the attribute check imports the module.
    """
    module, _, attr = target.partition(":")
    try:
        found = sys.modules.get(module) or importlib.util.find_spec(module)
    except (ModuleNotFoundError, ValueError):
        found = None
    if found is None:
        return module
    if attr:
        try:
            mod = importlib.import_module(module)
        except Exception as err:  # noqa: BLE001 - a broken module is a missing piece, with its reason
            return f"{module} (import fails: {type(err).__name__}: {err})"
        if not hasattr(mod, attr):
            return f"{module}.{attr}"
    return None


@cache
def expert_missing(name: str) -> str | None:
    """None when the expert is registered and its module exists, else what is missing."""
    try:
        from moegs.experts import get_spec
    except ImportError as err:
        return f"moegs.experts ({err})"
    try:
        spec = get_spec(name)
    except ValueError:
        return f"expert '{name}' (moegs.experts registry)"
    gone = module_missing(spec.target.partition(":")[0])
    return None if gone is None else f"expert '{name}' ({gone})"


def missing_pieces(kind: str, params: dict) -> list[str]:
    """What ``kind`` with ``params`` needs that the library lacks (``[]``: runnable)."""
    if KINDS.get(kind) is None:
        return []
    return list(dict.fromkeys(kind_module(kind).missing(dict(params))))


def experts_missing(names: list[str]) -> list[str]:
    return [m for m in (expert_missing(n) for n in names) if m]


TRAIN_LOOP = "moegs.train.loop:train"
LOAD_EXPERT = "moegs.train.entry:load_trained"
