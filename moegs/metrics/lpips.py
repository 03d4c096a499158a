"""LPIPS v0.1 (AlexNet backbone) in plain PyTorch, from the staged Keras weights.

Network (Zhang et al. 2018, ``lpips.LPIPS(net="alex")``): scaling layer ``(x - shift) / scale``; five
AlexNet slices ending at each ReLU (conv1 64 k11 s4 p2; maxpool 3/2, conv2 192 k5 p2; maxpool 3/2,
conv3 384 k3 p1; conv4 256 k3 p1; conv5 256 k3 p1); channel unit-normalisation (eps 1e-10); squared
difference; bias-free 1x1 linear heads; spatial mean; sum over the five layers.

**The input-scaling trap.** LPIPS was trained on inputs in [-1, 1]. Its scaling layer only re-centres
them, so inputs must be rescaled ``2 x - 1`` first ("pm1", correct, default). The 3DGS-lineage
``lpipsPyTorch.lpips(x, y)`` (3DGS, 4DGaussians, E-D3DGS, STG, Ex4DGS, MoE-GS) feeds [0, 1] images
straight into the scaling layer ("legacy01"): numbers are systematically different (usually lower)
and only comparable with other "legacy01" numbers.

Weights: ``<data_root>/lpips_weights/lpips_tf/alex/*.keras`` (Keras v3 zips read with h5py, no
TensorFlow). Loaded on first use, cached per weights folder, device and dtype; importing this module
reads nothing. Missing weights raise ``LPIPSUnavailable``; no number is ever made up.
"""

from __future__ import annotations

import io
import zipfile
from functools import lru_cache
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from moegs.metrics._images import as_batch, to_bchw, unbatch
from moegs.paths import data_root

LPIPS_NETS: tuple[str, ...] = ("alex",)
LPIPS_SCALINGS: dict[str, str] = {
    "pm1": "inputs in [0, 1] rescaled to [-1, 1] before the LPIPS scaling layer "
    "(correct; lpips normalize=True)",
    "legacy01": "inputs in [0, 1] fed unscaled (3DGS-lineage lpipsPyTorch, MoE-GS code; "
    "lpips normalize=False on [0, 1] images); a trap, kept to reproduce those numbers",
}
WEIGHTS_SUBDIR = "lpips_weights/lpips_tf"

_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
# (file, out channels, kernel, stride, padding, max-pool 3/2 before the conv)
_ALEX_SLICES = (
    ("slice_1_base", 64, 11, 4, 2, False),
    ("slice_2_base", 192, 5, 1, 2, True),
    ("slice_3_base", 384, 3, 1, 1, True),
    ("slice_4_base", 256, 3, 1, 1, False),
    ("slice_5_base", 256, 3, 1, 1, False),
)
_ALEX_LINS = tuple(f"lin{i}" for i in range(5))
_SLICE_VARS = "layers/sequential/layers/conv2d/vars"
_LIN_VARS = "conv_layer/layers/conv2d/vars"
_ALEX_FILES = tuple(f"{s[0]}.keras" for s in _ALEX_SLICES) + tuple(f"{n}.keras" for n in _ALEX_LINS)
MIN_SIZE = 31  # smallest H, W for which the second max-pool still has an input of 3


class LPIPSUnavailable(RuntimeError):
    """The LPIPS weights are not where ``moegs.paths.data_root()`` says they should be."""


def lpips_weights_dir(net: str = "alex") -> Path | None:
    """Folder expected to hold the ``net`` weights, or ``None`` without a data root."""
    root = data_root()
    return None if root is None else root / WEIGHTS_SUBDIR / net


def _check_net(net: str, fn: str) -> None:
    if net not in LPIPS_NETS:
        valid = ", ".join(repr(n) for n in LPIPS_NETS)
        raise ValueError(
            f"{fn}: unknown LPIPS net {net!r}; valid nets: {valid} (LPIPS-VGG weights are not staged)"
        )


def _check_scaling(scaling: str, fn: str) -> None:
    if scaling not in LPIPS_SCALINGS:
        valid = ", ".join(repr(s) for s in LPIPS_SCALINGS)
        raise ValueError(f"{fn}: unknown LPIPS scaling {scaling!r}; valid scalings: {valid}")


def lpips_available(net: str = "alex") -> bool:
    """Whether every weight file of ``net`` is present (nothing is loaded)."""
    folder = lpips_weights_dir(net)
    return net in LPIPS_NETS and folder is not None and all((folder / f).is_file() for f in _ALEX_FILES)


def _require_weights(net: str) -> Path:
    folder = lpips_weights_dir(net)
    if folder is None:
        raise LPIPSUnavailable(
            f"LPIPS-{net} weights unavailable: no data root. Set MOEGS_DATA to the folder holding "
            f"{WEIGHTS_SUBDIR}/{net}/ (default ../shared/data beside the repository)"
        )
    missing = [f for f in _ALEX_FILES if not (folder / f).is_file()]
    if missing:
        raise LPIPSUnavailable(
            f"LPIPS-{net} weights unavailable: looked in {folder}, missing {', '.join(missing)}"
        )
    return folder


def _read_keras_vars(path: Path, group: str) -> list[Tensor]:
    """The arrays ``group/0, group/1, ...`` of ``model.weights.h5`` inside a ``.keras`` zip."""
    import h5py

    with zipfile.ZipFile(path) as zf, h5py.File(io.BytesIO(zf.read("model.weights.h5")), "r") as h5:
        if group not in h5:
            raise LPIPSUnavailable(f"{path}: no '{group}' in model.weights.h5; not an lpips_torch2tf file")
        return [torch.from_numpy(h5[group][k][()]) for k in sorted(h5[group], key=int)]


def _to_oihw(kernel: Tensor) -> Tensor:
    """Keras kernel from lpips_torch2tf -> PyTorch ``[O, I, kh, kw]``.

    The converter stored ``swapaxes(swapaxes(w_oihw, 0, -1), 1, -2)``, i.e. ``[kw, kh, I, O]``, not
    HWIO (its TF model is fed transposed images). Reading it as HWIO transposes every kernel and
    misses the reference pair by ~0.03.
    """
    return kernel.permute(3, 2, 1, 0).contiguous()


@lru_cache(maxsize=4)
def _alex_state(folder: str) -> tuple[tuple[tuple[Tensor, Tensor], ...], tuple[Tensor, ...]]:
    """Read and check the AlexNet slices ``((weight, bias), ...)`` and linear heads, float32 CPU."""
    convs, lins = [], []
    in_ch = 3
    for name, out_ch, k, *_ in _ALEX_SLICES:
        path = Path(folder) / f"{name}.keras"
        kernel, bias = _read_keras_vars(path, _SLICE_VARS)
        weight = _to_oihw(kernel)
        if tuple(weight.shape) != (out_ch, in_ch, k, k) or tuple(bias.shape) != (out_ch,):
            raise LPIPSUnavailable(
                f"{path}: expected kernel [{out_ch}, {in_ch}, {k}, {k}] and bias [{out_ch}], "
                f"got {list(weight.shape)} and {list(bias.shape)}"
            )
        convs.append((weight.float(), bias.float()))
        in_ch = out_ch
    for name, (_, ch, *_) in zip(_ALEX_LINS, _ALEX_SLICES, strict=True):
        path = Path(folder) / f"{name}.keras"
        (kernel,) = _read_keras_vars(path, _LIN_VARS)
        weight = _to_oihw(kernel)
        if tuple(weight.shape) != (1, ch, 1, 1):
            raise LPIPSUnavailable(f"{path}: expected linear head [1, {ch}, 1, 1], got {list(weight.shape)}")
        lins.append(weight.float())
    return tuple(convs), tuple(lins)


class _AlexLPIPS(nn.Module):
    """Frozen LPIPS-Alex; ``forward(x, y)`` on ``[B, 3, H, W]`` network-range inputs -> ``[B]``."""

    def __init__(self, folder: str) -> None:
        super().__init__()
        convs, lins = _alex_state(folder)
        self.convs = nn.ModuleList()
        for (weight, bias), (_, out_ch, k, stride, pad, _) in zip(convs, _ALEX_SLICES, strict=True):
            conv = nn.Conv2d(weight.shape[1], out_ch, k, stride=stride, padding=pad)
            conv.weight.data.copy_(weight)
            conv.bias.data.copy_(bias)
            self.convs.append(conv)
        self.lins = nn.ModuleList()
        for weight in lins:
            lin = nn.Conv2d(weight.shape[1], 1, 1, bias=False)
            lin.weight.data.copy_(weight)
            self.lins.append(lin)
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    def _features(self, x: Tensor) -> list[Tensor]:
        h = (x - self.shift) / self.scale
        feats = []
        for conv, (*_, pool) in zip(self.convs, _ALEX_SLICES, strict=True):
            if pool:
                h = F.max_pool2d(h, kernel_size=3, stride=2)
            h = F.relu(conv(h))
            # vector_norm has a zero subgradient at 0, so an all-zero ReLU column does not give NaN grads
            feats.append(h / (torch.linalg.vector_norm(h, dim=1, keepdim=True) + 1e-10))
        return feats

    def forward(self, x: Tensor, y: Tensor, mask: Tensor | None = None) -> Tensor:
        """``[B]`` distances; with ``mask [B, 1, H, W]``, the mask-weighted mean of the spatial map."""
        total = x.new_zeros(x.shape[0])
        for fx, fy, lin in zip(self._features(x), self._features(y), self.lins, strict=True):
            layer = lin((fx - fy).square())  # [B, 1, h, w]
            if mask is None:
                total = total + layer.mean(dim=(1, 2, 3))
            else:  # lpips spatial=True: each layer's map upsampled bilinearly to the image size
                up = F.interpolate(layer, size=x.shape[-2:], mode="bilinear", align_corners=False)
                total = total + (up * mask).sum(dim=(1, 2, 3)) / mask.sum(dim=(1, 2, 3)).clamp_min(1e-12)
        return total


@lru_cache(maxsize=8)
def _network(folder: str, device: torch.device, dtype: torch.dtype) -> _AlexLPIPS:
    """The network read on the host, then moved to ``device``. Its layers' default initialisation, which
    the read weights replace, draws from a forked generator: a run that scores its first view mid-training
    (``select_best_at``, ``eval_every``) trains on as it would have without."""
    with torch.random.fork_rng(devices=[]), torch.device("cpu"):
        network = _AlexLPIPS(folder)
    return network.to(device=device, dtype=dtype)


def lpips(
    pred: Tensor, target: Tensor, net: str = "alex", scaling: str = "pm1", mask: Tensor | None = None
) -> Tensor:
    """LPIPS distance, one value per image (lower is more similar; 0 for identical images).

    Differentiable with respect to both inputs (the network is frozen), so usable as a loss.

    Args:
        pred: ``[H, W, 3]`` or ``[B, H, W, 3]`` float in [0, 1], at least 31x31.
        target: same shape.
        net: backbone; only "alex" is staged (``LPIPS_NETS``).
        scaling: "pm1" (default, correct) or "legacy01" (the 3DGS-lineage trap), see ``LPIPS_SCALINGS``.
        mask: optional region ``[H, W]`` (``[B, H, W]`` for a batch) of weights in [0, 1]: the result is
            the mask-weighted mean of the spatial LPIPS map (``lpips.LPIPS(spatial=True)``: every layer's
            distance map upsampled bilinearly to the image size, then summed over layers).

    Returns:
        0-dim tensor for one image, ``[B]`` for a batch.

    Raises:
        LPIPSUnavailable: the weights are missing; the message names the folder looked in.
    """
    _check_net(net, "lpips")
    _check_scaling(scaling, "lpips")
    x, y, batched = as_batch(pred, target, "lpips")
    if x.shape[-1] != 3:
        raise ValueError(f"lpips: `pred` must have 3 (RGB) channels, got {x.shape[-1]}")
    h, w = x.shape[1:3]
    if h < MIN_SIZE or w < MIN_SIZE:
        raise ValueError(
            f"lpips: images must be at least {MIN_SIZE}x{MIN_SIZE} pixels for AlexNet, got {h}x{w}"
        )
    network = _network(str(_require_weights(net)), x.device, x.dtype)
    x, y = to_bchw(x), to_bchw(y)
    if scaling == "pm1":
        x, y = 2.0 * x - 1.0, 2.0 * y - 1.0
    weights = None
    if mask is not None:
        weights = (
            mask.to(x.dtype).reshape(x.shape[0], 1, h, w) if mask.numel() == x.shape[0] * h * w else None
        )
        if weights is None:
            raise ValueError(f"lpips: mask must have {h}x{w} values per image, got shape {list(mask.shape)}")
    return unbatch(network(x, y, weights), batched)


class LPIPS(nn.Module):
    """Module form of ``lpips``. Checks the weights at construction; holds no parameters itself
    (the frozen network is cached per device, so it never lands in a model's state_dict)."""

    def __init__(self, net: str = "alex", scaling: str = "pm1") -> None:
        super().__init__()
        _check_net(net, "LPIPS")
        _check_scaling(scaling, "LPIPS")
        _alex_state(str(_require_weights(net)))
        self.net, self.scaling = net, scaling

    def forward(self, pred: Tensor, target: Tensor) -> Tensor:
        return lpips(pred, target, self.net, self.scaling)

    def extra_repr(self) -> str:
        return f"net={self.net!r}, scaling={self.scaling!r}"
