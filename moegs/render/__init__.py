"""Rasterization: the only place that turns Gaussians into pixels.

    out = rasterize(frame, camera)           # out.image [H, W, C], out.alpha [H, W], out.depth [H, W]
    multi = rasterize_multi(frames, camera)  # multi.images [K, H, W, C], one transmittance per expert

Both run one pipeline (``pipeline._render``): colours (SH evaluated in torch when the frame has ``sh``) ->
3D covariances -> EWA projection (``projection.py``) -> ONE compositing call over all Gaussians
with camera z appended as an extra channel -> expected depth -> background.

Backends (``backend=``):

* ``"torch"``: ``_torch._composite``, the exact pure-PyTorch reference and test oracle.
* ``"cpu"``: the compiled C/OpenMP kernel ``_cpu.composite`` (same contract), CPU tensors only.
* ``"cuda"``: gsplat on CUDA tensors (``_cuda.py``; matches the reference only to a tolerance).
* ``"auto"`` (default): ``cuda`` for CUDA tensors, ``cpu`` for CPU tensors; when that backend is not
  available it falls back to ``torch`` with one ``RuntimeWarning`` per process and reason.
"""

from moegs.render.multi import MultiRenderOutput, rasterize_multi
from moegs.render.pipeline import BACKENDS, RenderOutput, frame_colors, rasterize

__all__ = ["BACKENDS", "MultiRenderOutput", "RenderOutput", "frame_colors", "rasterize", "rasterize_multi"]
