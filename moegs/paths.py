"""Where data and caches live. ``MOEGS_DATA`` overrides the data root."""

from __future__ import annotations

import os
from pathlib import Path

_REPO = Path(__file__).resolve().parent.parent


def data_root() -> Path | None:
    """The data root: ``$MOEGS_DATA``, else ``../shared/data`` beside the repository if it exists."""
    env = os.environ.get("MOEGS_DATA")
    if env:
        return Path(env).expanduser()
    default = _REPO.parent / "shared" / "data"
    return default if default.is_dir() else None


def require_data(relative: str, what: str) -> Path:
    """``data_root() / relative``, or ``FileNotFoundError`` saying which path and layout was expected."""
    root = data_root()
    if root is None:
        raise FileNotFoundError(
            f"{what}: no data root. Set MOEGS_DATA to the folder holding '{relative}' "
            f"(default ../shared/data beside the repository)."
        )
    path = root / relative
    if not path.exists():
        raise FileNotFoundError(f"{what}: expected {path} (MOEGS_DATA={root}) but it does not exist")
    return path


def cache_root() -> Path:
    """Writable cache for generated scenes, decoded images and test runs: ``$MOEGS_CACHE``, else ``.cache/``
    in a source checkout, else the user's cache folder (``$XDG_CACHE_HOME/moegs``, ``~/.cache/moegs``), never
    the install tree."""
    env = os.environ.get("MOEGS_CACHE")
    if env:
        return Path(env).expanduser()
    if (_REPO / "pyproject.toml").is_file():
        return _REPO / ".cache"
    return Path(os.environ.get("XDG_CACHE_HOME") or "~/.cache").expanduser() / "moegs"
