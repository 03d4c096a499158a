"""Result JSON files: schema, atomic writes, validation.

One file per evaluated cell (``Workspace.result_path``). Fields::

    schema        "moegs.bench.result/1"
    status        "ok" | "failed"
    key           the task key (must match the file name and the task)
    task          action, kind, params, scene, scene_kwargs, preset, seed
    identity      everything the key hashes (incl. preset definition hash and code version)
    metrics       {"psnr": ..., "ssim": ..., "lpips": ..., "fps": ..., "memory_mb": ..., ...}
    metric_profile  moegs.metrics profile dict (name, id and every setting)
    per_view      per test view: key, time, psnr, ssim, lpips (and region metrics)
    details       kind-specific extras (speed protocol, pruning stats, trajectories summary ...)
    files         {name: sha256} of arrays under <key>.files/
    scene         name, kwargs, real, stand_in text, summary, input hash
    artifacts     {key: {kind, params, config, files: {name: sha256}, build_seconds, train_seconds}}
                  of the artefacts used (config: the expert and training config the loop saved)
    preset        the bench preset definition
    hashes        task key, scene input hash, checkpoint file hashes
    timings       {"total_s", "load_s", "eval_s"}
    versions      python, torch, platform, moegs code version and git commit
    log           path of the task's log
    error         (failed only) exception text and traceback
    created       ISO time
    content_sha256  sha256 of the canonical JSON of every other field: a file edited by hand (or
                  damaged) is refused and the cell recomputed
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Any

from bench.tasks import Task
from moegs.atomic import atomic_path

SCHEMA = "moegs.bench.result/1"
REQUIRED = ("schema", "status", "key", "task", "metrics", "versions", "timings", "content_sha256")
HASH_FIELD = "content_sha256"


class ResultError(ValueError):
    """A result file is unreadable or inconsistent; the message names the file."""


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through ``atomic_path``."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_json_atomic(path: Path, payload: dict[str, Any]) -> None:
    """Write ``payload`` to ``path`` as sorted, indented JSON (``write_text_atomic``)."""
    write_text_atomic(path, json.dumps(payload, indent=1, sort_keys=True, default=str) + "\n")


def content_hash(payload: dict[str, Any]) -> str:
    """sha256 of ``payload``'s canonical JSON, its ``content_sha256`` field left out."""
    body = {k: v for k, v in payload.items() if k != HASH_FIELD}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), default=str, allow_nan=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def write_result(path: Path, payload: dict[str, Any]) -> None:
    """Write one cell's result atomically with its ``content_sha256``."""
    payload = json.loads(json.dumps(payload, default=str))  # what the file will hold, hashed as read back
    write_json_atomic(path, {**payload, HASH_FIELD: content_hash(payload)})


def read_result(path: Path) -> dict[str, Any]:
    """Parse and check one result file; ``ResultError`` names the file and the problem."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ResultError(f"{path}: no such result file") from None
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ResultError(f"{path}: not valid JSON ({err})") from None
    if not isinstance(data, dict):
        raise ResultError(f"{path}: expected a JSON object, got {type(data).__name__}")
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise ResultError(f"{path}: missing field(s) {missing}")
    if data["schema"] != SCHEMA:
        raise ResultError(f"{path}: schema {data['schema']!r}, expected {SCHEMA!r}")
    if data["status"] not in ("ok", "failed"):
        raise ResultError(f"{path}: status must be 'ok' or 'failed', got {data['status']!r}")
    if Path(path).stem != data["key"]:
        raise ResultError(f"{path}: key {data['key']!r} does not match the file name")
    if not isinstance(data["metrics"], dict):
        raise ResultError(f"{path}: 'metrics' must be an object")
    if data[HASH_FIELD] != content_hash(data):
        raise ResultError(f"{path}: content does not match its content_sha256 (edited or damaged)")
    return data


def load_valid(path: Path, task: Task) -> dict[str, Any] | None:
    """The result of ``task`` if its file exists, parses, is ``ok`` and belongs to ``task``; else None.

    A file that exists but is broken raises ``ResultError`` (so the caller can say which file).
    """
    if not Path(path).is_file():
        return None
    data = read_result(path)
    if data["key"] != task.key:
        raise ResultError(f"{path}: result key {data['key']} is not the task key {task.key}")
    return data if data["status"] == "ok" else None


def now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")
