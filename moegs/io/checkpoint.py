"""Checkpoint files: one safetensors file holding every tensor of a nested state, with the rest of
the state (numbers, strings, lists, dicts) as JSON in the file's metadata.

A state is a tree of dicts (string or int keys) and lists whose leaves are tensors or JSON values.
Tensors are stored under their path (``"optim/means/state/0/exp_avg"``) and replaced in the JSON by
``{"__tensor__": path}``. Writes are atomic (temporary file + ``os.replace``), so an interrupted
write never damages the previous checkpoint (``moegs.atomic``). Each file records the SHA-256 of its
content (the JSON and every tensor's bytes), checked on every read: a file changed or damaged after it
was written is refused, never resumed from or evaluated. Files written before digests existed read as
they are.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import torch
from safetensors import safe_open
from safetensors.torch import save_file
from torch import Tensor

from moegs.atomic import atomic_path
from moegs.errors import IntegrityError

_META_KEY = "moegs"
_DIGEST_KEY = "moegs_sha256"
_TENSOR = "__tensor__"
_INT_KEYS = "__int_keys__"


def _split(tree: Any, path: str, tensors: dict[str, Tensor]) -> Any:
    if isinstance(tree, Tensor):
        tensors[path] = tree.detach().cpu().contiguous().clone()
        return {_TENSOR: path}
    if isinstance(tree, dict):
        keys = list(tree)
        if any(not isinstance(k, str | int) or isinstance(k, bool) for k in keys):
            raise TypeError(f"checkpoint: keys at {path or '/'} must be str or int, got {keys}")
        out = {str(k): _split(v, f"{path}/{k}" if path else str(k), tensors) for k, v in tree.items()}
        int_keys = [str(k) for k in keys if isinstance(k, int)]
        if int_keys:
            out[_INT_KEYS] = int_keys
        return out
    if isinstance(tree, list | tuple):
        return [_split(v, f"{path}/{i}", tensors) for i, v in enumerate(tree)]
    if tree is None or isinstance(tree, bool | int | float | str):
        return tree
    raise TypeError(f"checkpoint: cannot store {type(tree).__name__} at {path or '/'}")


def _join(tree: Any, tensors: dict[str, Tensor]) -> Any:
    if isinstance(tree, dict):
        if set(tree) == {_TENSOR}:
            return tensors[tree[_TENSOR]]
        int_keys = set(tree.get(_INT_KEYS, ()))
        return {int(k) if k in int_keys else k: _join(v, tensors) for k, v in tree.items() if k != _INT_KEYS}
    if isinstance(tree, list):
        return [_join(v, tensors) for v in tree]
    return tree


def content_digest(meta: str, tensors: dict[str, Tensor]) -> str:
    """SHA-256 of a checkpoint's JSON and of every tensor (name, dtype, shape, bytes), in name order."""
    h = hashlib.sha256(meta.encode())
    for name in sorted(tensors):
        t = tensors[name].detach().cpu().contiguous()
        h.update(f"\0{name}\0{t.dtype}\0{tuple(t.shape)}\0".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


def save_checkpoint(path: str | Path, state: dict) -> Path:
    """Write ``state`` atomically to ``path`` (``.safetensors``) with its content digest; returns the
    path."""
    path = Path(path)
    tensors: dict[str, Tensor] = {}
    meta = json.dumps(_split(state, "", tensors), allow_nan=False)
    metadata = {_META_KEY: meta, _DIGEST_KEY: content_digest(meta, tensors)}
    with atomic_path(path) as tmp:
        save_file(tensors, str(tmp), metadata=metadata)
    return path


def load_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> dict:
    """Read a file written by :func:`save_checkpoint`; tensors land on ``device``."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        with safe_open(str(path), framework="pt", device="cpu") as f:
            metadata = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118 - safe_open has no iterator
    except Exception as err:  # safetensors raises its own SafetensorError (and OSError on short reads)
        reason = " ".join(str(err).split())
        raise IntegrityError(f"{path}: not a readable safetensors file ({reason})") from None
    meta, digest = metadata.get(_META_KEY), metadata.get(_DIGEST_KEY)
    if meta is None:
        raise IntegrityError(
            f"{path}: a safetensors file but not a moegs checkpoint (no '{_META_KEY}' metadata)"
        )
    if digest is not None and digest != content_digest(meta, tensors):
        raise IntegrityError(
            f"{path}: its content does not match the digest written with it (changed or damaged after it "
            "was written); train again, or delete the file to start that run over"
        )
    if str(device) != "cpu":
        tensors = {k: t.to(device) for k, t in tensors.items()}
    try:
        tree = json.loads(meta)
    except json.JSONDecodeError as err:
        raise IntegrityError(f"{path}: damaged checkpoint metadata ({err})") from None
    return _join(tree, tensors)


def write_json(path: str | Path, value: Any) -> Path:
    """Write ``value`` as indented JSON atomically."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        json.dump(value, f, indent=2, allow_nan=True)
        f.write("\n")
    return path


def read_json(path: str | Path, what: str = "JSON file") -> dict[str, Any]:
    """A JSON object from ``path``; errors name the file (``FileNotFoundError``, ``IntegrityError``)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} {path} does not exist")
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise IntegrityError(f"{path}: not valid JSON ({err})") from None
    if not isinstance(value, dict):
        raise IntegrityError(f"{path}: expected a JSON object, got {type(value).__name__}")
    return value
