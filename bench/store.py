"""Where everything a run writes lives, and the content-addressed artefact store.

Layout under the workspace root (``$MOEGS_BENCH_DIR``, default ``runs/bench`` in the working directory,
never in the install tree)::

    store/<kind>/<key>/            one artefact (checkpoint files + artifact.json + DONE)
    results/<preset>/<kind>/<key>.json        one evaluated cell
    results/<preset>/<kind>/<key>.files/      arrays a figure needs (npz, png)
    logs/<action>/<kind>/<key>.log            stdout/stderr of the task's process
    jobs/<key>.json                           the task description handed to the worker

Artefacts are built under a per-key file lock into a temporary folder that is renamed into place, so
concurrent workers needing the same expert train it once and an interrupted build leaves nothing
that looks finished. Before a finished artefact is used, each of its files is checked against the
sha256 recorded in ``artifact.json`` when it was built (once per process); a folder that fails is moved
aside to ``<key>.corrupt-<time>`` and built again.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from bench.codedeps import loaded_modules
from bench.keys import file_sha256
from bench.tasks import Task

WORKSPACE_ENV = "MOEGS_BENCH_DIR"
DONE = "DONE"
META = "artifact.json"


class ArtifactError(RuntimeError):
    """An artefact is missing or broken; the message names its folder."""


class Workspace:
    """Paths of one benchmark workspace."""

    def __init__(self, root: str | Path | None = None) -> None:
        env = os.environ.get(WORKSPACE_ENV)
        self.root = Path(root or env or Path.cwd() / "runs" / "bench").expanduser().resolve()
        self._verified: set[str] = set()

    def __repr__(self) -> str:
        return f"Workspace({self.root})"

    # ------------------------------------------------------------------ paths
    def artifact_dir(self, task: Task) -> Path:
        return self.root / "store" / task.kind / task.key

    def result_path(self, task: Task) -> Path:
        return self.root / "results" / task.preset / task.kind / f"{task.key}.json"

    def files_dir(self, task: Task) -> Path:
        return self.root / "results" / task.preset / task.kind / f"{task.key}.files"

    def log_path(self, task: Task) -> Path:
        return self.root / "logs" / task.action / task.kind / f"{task.key}.log"

    def job_path(self, task: Task) -> Path:
        return self.root / "jobs" / f"{task.key}.json"

    def failure_path(self, task: Task) -> Path:
        """Where a failed build leaves its error (the folder itself never looks finished)."""
        return self.root / "store" / task.kind / f"{task.key}.failed.json"

    @property
    def scene_hash_cache(self) -> Path:
        return self.root / "scene_hashes.json"

    # ------------------------------------------------------------------ artefacts
    def is_built(self, task: Task) -> bool:
        """Finished and intact (every file matches its recorded sha256)."""
        if not (self.artifact_dir(task) / DONE).is_file():
            return False
        try:
            self.verify(task)
        except ArtifactError:
            return False
        return True

    def verify(self, task: Task) -> None:
        """Check every file of a finished artefact against ``artifact.json``; ``ArtifactError`` names the
        first file that is missing or differs."""
        if task.key in self._verified:
            return
        folder = self.artifact_dir(task)
        files = self.artifact_meta(task).get("files")
        if not isinstance(files, dict):
            raise ArtifactError(f"artefact {folder}: {META} records no file hashes")
        for name, recorded in sorted(files.items()):
            path = folder / name
            if not path.is_file():
                raise ArtifactError(f"{path}: missing (recorded in {folder / META})")
            actual = file_sha256(path)
            if actual != recorded:
                raise ArtifactError(
                    f"{path}: sha256 {actual[:12]}... differs from {recorded[:12]}... recorded at build time"
                )
        self._verified.add(task.key)

    def _intact(self, task: Task, warn: Callable[[str], None]) -> bool:
        """Whether a finished, intact artefact is there; a damaged one is moved aside (and ``warn`` told)."""
        final = self.artifact_dir(task)
        if not (final / DONE).is_file():
            return False
        try:
            self.verify(task)
            return True
        except ArtifactError as err:
            aside = final.with_name(f"{final.name}.corrupt-{time.strftime('%Y%m%dT%H%M%S')}")
            final.rename(aside)
            warn(f"WARNING damaged artefact, rebuilding: {err} (moved to {aside})")
            return False

    def artifact_meta(self, task: Task) -> dict[str, Any]:
        """``artifact.json`` of a finished artefact; ``ArtifactError`` naming the folder otherwise."""
        folder = self.artifact_dir(task)
        if not (folder / DONE).is_file():
            raise ArtifactError(f"artefact {task.slug} is not built (expected {folder}/{DONE})")
        try:
            return json.loads((folder / META).read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise ArtifactError(f"artefact {folder}: unreadable {META} ({err})") from None

    @contextmanager
    def _lock(self, task: Task):
        lock_path = self.artifact_dir(task).with_suffix(".lock")
        lock_path.parent.mkdir(parents=True, exist_ok=True)
        with open(lock_path, "w") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)

    def ensure(
        self, task: Task, build: Callable[[Path], dict[str, Any]], warn: Callable[[str], None] = print
    ) -> Path:
        """The artefact folder of ``task``, verified, or built with ``build(tmp_dir) -> meta``."""
        final = self.artifact_dir(task)
        if task.key in self._verified and (final / DONE).is_file():
            return final
        with self._lock(task):
            if self._intact(task, warn):  # also: built by another worker while we waited
                return final
            # one writer at a time (the lock): a stable partial folder lets a build resume its checkpoint
            tmp = final.with_name(f"{final.name}.partial")
            tmp.mkdir(parents=True, exist_ok=True)
            start = time.perf_counter()
            meta = build(tmp) or {}
            meta = {
                **meta,
                "task": task.to_dict(),
                "key": task.key,
                "identity": task.identity(),
                "build_seconds": time.perf_counter() - start,
                "modules_loaded": loaded_modules(),
                "files": {p.name: file_sha256(p) for p in sorted(tmp.iterdir()) if p.is_file()},
            }
            (tmp / META).write_text(json.dumps(meta, indent=1, sort_keys=True, default=str))
            shutil.rmtree(final, ignore_errors=True)
            tmp.rename(final)
            (final / DONE).write_text(time.strftime("%Y-%m-%dT%H:%M:%S%z"))
            self.failure_path(task).unlink(missing_ok=True)
            self._verified.add(task.key)
        return final
