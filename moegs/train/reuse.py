"""Reusing a finished run: only when its folder's ``config.json`` records the config the recipe gives now.

``moegs train``, ``moegs compare`` and ``moegs route`` leave a finished expert run alone. Without this check a
changed recipe (another ``--iterations`` or ``--set``, a new per-scene value, a library default that moved)
would silently reuse the old run's result. An interrupted run is not affected: resuming its checkpoint
already refuses another config (``moegs.train.loop``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from moegs.io import read_json, to_dict
from moegs.io.config import config_changes
from moegs.recipes import Recipe
from moegs.train.entry import finished_run
from moegs.train.loop import RUN_ONLY_FIELDS


class StaleRunError(ValueError):
    """A folder holds a finished run of another config."""


def finished_run_of(recipe: Recipe, out_dir: str | Path, remedy: str) -> dict[str, Any] | None:
    """The result of the finished run in ``out_dir`` (see ``finished_run``) when it was trained with
    ``recipe``'s config, None when no run there is finished.

    Raises:
        StaleRunError: the finished run's config differs (fields in ``RUN_ONLY_FIELDS`` aside); the message
            names the folder, the first fields that differ and ``remedy`` (what the user can do).
    """
    result = finished_run(out_dir)
    if result is None:
        return None
    recorded = read_json(Path(out_dir) / "config.json", "run config")
    changed = config_changes(recorded.get("config", {}), to_dict(recipe.config), RUN_ONLY_FIELDS)
    if changed:
        more = f" and {len(changed) - 6} more" if len(changed) > 6 else ""
        raise StaleRunError(
            f"{out_dir} holds a finished run of another {recipe.expert} config (changed: "
            f"{', '.join(changed[:6])}{more}), so it is not reused; {remedy}"
        )
    return result
