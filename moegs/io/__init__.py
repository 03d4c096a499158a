"""Checkpoints (safetensors + JSON metadata), config dicts and 3DGS-compatible PLY files."""

from moegs.io.checkpoint import load_checkpoint, read_json, save_checkpoint, write_json
from moegs.io.config import from_dict, to_dict
from moegs.io.ply import export_ply, read_ply

__all__ = [
    "export_ply",
    "from_dict",
    "load_checkpoint",
    "read_ply",
    "read_json",
    "save_checkpoint",
    "to_dict",
    "write_json",
]
