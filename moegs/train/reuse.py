"""Reusing a finished run, and saying when its config is not the one the recipe gives now.

``moegs train``, ``moegs compare`` and ``moegs route`` leave a finished expert run alone. Its folder's
``config.json`` records the config it was trained with; a recipe that changed since (another ``--iterations``
or ``--set``, a new per-scene value, a library default that moved) must not pass silently. ``moegs train``
refuses such a folder (``finished_run_of``); ``compare`` and ``route`` reuse it, as a user may have trained
an expert on purpose with other settings, but name the changed fields (``reusable_run``). An
interrupted run is not affected: resuming its checkpoint already refuses another config
(``moegs.train.loop``).
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


RUN_FIELDS = {"expert": str, "scene": str, "train": dict}
"""Fields of a run's ``config.json`` the commands read, with their JSON types."""


def read_run_config(path: str | Path, fields: dict[str, type] = RUN_FIELDS) -> tuple[Path, dict[str, Any]]:
    """A run folder and its ``config.json``, each of ``fields`` checked for its JSON type; the errors name
    the folder or file and the field."""
    run = Path(path)
    config = run / "config.json"
    if not config.is_file():
        raise FileNotFoundError(f"{run} is not a training run (no config.json); train one with `moegs train`")
    meta = read_json(config, "run config")
    for field, kind in fields.items():
        if not isinstance(meta.get(field), kind):
            raise ValueError(f"{config}: field {field!r} must be a {kind.__name__}, got {meta.get(field)!r}")
    return run, meta


def config_changes_of(recipe: Recipe, out_dir: str | Path) -> list[str]:
    """Dotted fields of the expert config that ``out_dir/config.json`` records with another value than
    ``recipe``'s (``RUN_ONLY_FIELDS`` aside); empty when they agree."""
    recorded = read_json(Path(out_dir) / "config.json", "run config")
    return config_changes(recorded.get("config", {}), to_dict(recipe.config), RUN_ONLY_FIELDS)


def describe_changes(changed: list[str], shown: int = 6) -> str:
    """``"a, b, c and 2 more"``: the first ``shown`` changed fields."""
    more = f" and {len(changed) - shown} more" if len(changed) > shown else ""
    return ", ".join(changed[:shown]) + more


def reusable_run(recipe: Recipe, out_dir: str | Path) -> tuple[dict[str, Any] | None, list[str]]:
    """``(result, changed)``: the finished run's result in ``out_dir`` (see ``finished_run``; None when no
    run there is finished) and the fields its config changed from ``recipe``'s (``config_changes_of``;
    empty when there is no finished run or the configs agree)."""
    result = finished_run(out_dir)
    return result, [] if result is None else config_changes_of(recipe, out_dir)


def finished_run_of(recipe: Recipe, out_dir: str | Path, remedy: str) -> dict[str, Any] | None:
    """The result of the finished run in ``out_dir`` when it was trained with ``recipe``'s config, None when
    no run there is finished.

    Raises:
        StaleRunError: the finished run's config differs; the message names the folder, the changed fields
            and ``remedy`` (what the user can do).
    """
    result, changed = reusable_run(recipe, out_dir)
    if changed:
        raise StaleRunError(
            f"{out_dir} holds a finished run of another {recipe.expert} config (changed: "
            f"{describe_changes(changed)}), so it is not reused; {remedy}"
        )
    return result
