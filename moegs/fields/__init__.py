"""Shared encoders for the deformation fields: positional encoding, HexPlane, hash grids, MLP blocks."""

from moegs.fields.hashgrid import DecomposedHashGrid4D, HashGrid, smoothstep
from moegs.fields.hexplane import HexPlane, plane_smoothness, sample_plane
from moegs.fields.mlp import Heads, SkipMLP, mlp, xavier_weights_
from moegs.fields.positional import PositionalEncoding, positional_encoding

__all__ = [
    "DecomposedHashGrid4D",
    "HashGrid",
    "Heads",
    "HexPlane",
    "PositionalEncoding",
    "SkipMLP",
    "mlp",
    "plane_smoothness",
    "positional_encoding",
    "sample_plane",
    "smoothstep",
    "xavier_weights_",
]
