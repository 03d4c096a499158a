"""What ``moegs view`` opens: one trained expert run, several of one scene, or a MoE-GS router folder.

    model = load_model(["runs/route_mutant/router_vapr"])   # or ["runs/grid4d"], or [run_a, run_b]
    model.names, model.modes, model.sources                  # experts, render modes, rgb sources
    rgb, alpha, depth = model.render_layers(camera, "blend", need_depth=True)

A router folder (``router.safetensors``) routes the expert runs of its ``runs.json``; a ``moegs route``
output folder holding one ``router_<variant>/`` opens that router. Each expert's rasterizer inputs at one
time are kept (``ImageCache``), so orbiting at a fixed time only rasterizes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from moegs.viewer.render import BLEND, modes_of, sources_of


def router_folder(path: Path) -> Path | None:
    """The router folder ``path`` is (``router.safetensors``) or holds as its one ``router_*/``; None for
    neither; ``ValueError`` when it holds several."""
    from moegs.moe.model import ROUTER_CHECKPOINT

    if (path / ROUTER_CHECKPOINT).is_file():
        return path
    routers = sorted(p.parent for p in path.glob(f"router_*/{ROUTER_CHECKPOINT}"))
    if len(routers) > 1:
        names = ", ".join(p.name for p in routers)
        raise ValueError(f"{path} holds several routers ({names}); open one of them")
    return routers[0] if routers else None


@dataclass
class ViewModel:
    """Trained experts of one scene, with their router for MoE-GS, on one device.

    Attributes:
        scene: the scene they trained on (placed on the experts' device).
        experts: the trained experts, in eval mode.
        moe: the ``MoEGS`` model of a router folder, or None.
        backend: the rasterizer backend the runs recorded (``auto``: the compiled kernel on the CPU,
            gsplat on CUDA).
        label: what was opened, for the page title.
    """

    scene: object
    experts: list
    moe: object | None
    backend: str
    label: str
    cache: object = field(default=None, repr=False)

    def __post_init__(self) -> None:
        from moegs.data.scene import ImageCache
        from moegs.experts.base import splat_inputs_bytes

        self.cache = ImageCache(max_items=4 * len(self.experts), nbytes=splat_inputs_bytes)

    @property
    def names(self) -> list[str]:
        """Expert names, numbered when one expert appears twice."""
        names = [e.name for e in self.experts]
        return [f"{n} #{k}" if names.count(n) > 1 else n for k, n in enumerate(names)]

    @property
    def modes(self) -> list[str]:
        return modes_of(self.names, self.moe is not None)

    @property
    def sources(self) -> list[str]:
        return sources_of(self.names, self.moe is not None)

    @property
    def device(self) -> torch.device:
        return self.scene.background.device

    @property
    def num_gaussians(self) -> int:
        return sum(e.num_gaussians for e in self.experts)

    def views(self) -> list[tuple[str, object]]:
        """``(label, view)`` of the scene's test views, then its training views, e.g. ``test 3 (t=0.25)``."""
        out = []
        for split, views in (("test", self.scene.test), ("train", self.scene.train)):
            out += [(f"{split} {i} (t={v.camera.time:.2f})", v) for i, v in enumerate(views)]
        return out

    def times(self) -> list[float]:
        """Sorted distinct times of the training views."""
        return self.scene.times.tolist()

    def truth(self, view) -> np.ndarray:
        """uint8 ``[H, W, 3]`` ground-truth image of a dataset view."""
        from moegs.viewer.render import to_u8

        return to_u8(view.image())

    # -- rendering ---------------------------------------------------------------------------------------
    def _inputs(self, k: int, camera):
        expert = self.experts[k]
        key = (k, expert.splat_inputs_key(camera))
        return self.cache.get(key, lambda: expert.splat_inputs(camera, self.scene.background))

    @torch.no_grad()
    def render_moe(self, camera):
        """The routed view (``MoERender``: image ``[H, W, 3]``, gates ``[K, H, W]``, expert_images)."""
        camera = camera.to(self.device)
        inputs = [self._inputs(k, camera) for k in range(len(self.experts))]
        return self.moe.render(camera, self.scene.background, inputs=inputs)

    @torch.no_grad()
    def render_expert(self, k: int, camera):
        """``(rgb [H, W, 3], alpha [H, W], depth [H, W])`` of expert ``k``."""
        from moegs.experts.base import render_splat_inputs

        camera = camera.to(self.device)
        rgb, out, _ = render_splat_inputs(self._inputs(k, camera), camera, self.backend)
        return rgb, out.alpha, out.depth

    @torch.no_grad()
    def render_layers(self, camera, source: str, need_depth: bool = True):
        """``(rgb, alpha, depth)`` of ``source``: an expert, or the MoE-GS blend (its alpha and depth are
        the experts' weighted by the gates; None without ``need_depth``)."""
        if source != BLEND:
            return self.render_expert(self.names.index(source), camera)
        out = self.render_moe(camera)
        if not need_depth:
            return out.image, None, None
        layers = [self.render_expert(k, camera) for k in range(len(self.experts))]
        alpha = sum(g * a for g, (_, a, _) in zip(out.gates, layers, strict=True))
        depth = sum(g * d for g, (_, _, d) in zip(out.gates, layers, strict=True))
        return out.image, alpha, depth


def _load_runs(paths: list[Path], device):
    """``(scene, experts, backend)`` of finished run folders of one scene (``moegs.route.load_runs``)."""
    from moegs.route import load_runs
    from moegs.train.entry import load_trained

    runs, scene = load_runs(paths)
    experts = [load_trained(r.path, scene, expect=r.expert, device=device)[0] for r in runs]
    return scene.to(device or "cpu"), experts, runs[0].meta["train"].get("backend", "auto")


def load_model(paths: list[str | Path], device=None) -> ViewModel:
    """The ``ViewModel`` of ``paths`` on ``device`` (None: the CPU): one run folder, several of one scene,
    or one router folder (or a route folder holding one). Errors name the folder and what it lacks."""
    from moegs.io import read_json

    folders = [Path(p) for p in paths]
    for folder in folders:
        if not folder.is_dir():
            raise FileNotFoundError(
                f"{folder} is no folder; give a run folder (moegs train) or a router folder (moegs route)"
            )
    router = router_folder(folders[0]) if len(folders) == 1 else None
    if router is not None:
        from moegs.moe import load_moe
        from moegs.route import RUNS_RECORD

        record = router / RUNS_RECORD
        if not record.is_file():
            raise FileNotFoundError(f"{router} has no {RUNS_RECORD} naming its expert runs; route them again")
        runs = [router / r for r in read_json(record, "router runs")["runs"]]
        scene, experts, backend = _load_runs(runs, device)
        moe = load_moe(router, experts, scene)
        return ViewModel(scene, experts, moe, moe.config.backend or backend, f"MoE-GS {router}")
    for folder in folders:
        if not (folder / "config.json").is_file():
            raise FileNotFoundError(
                f"{folder} is no run: it has no config.json (a `moegs train` run) and no router.safetensors "
                "(a `moegs route` router folder)"
            )
    if len(folders) > 1:
        scene, experts, backend = _load_runs(folders, device)
        return ViewModel(scene, experts, None, backend, ", ".join(map(str, folders)))
    from moegs.cli import _load_run

    _, meta, scene, expert = _load_run(str(folders[0]), device)
    return ViewModel(scene, [expert], None, meta["train"].get("backend", "auto"), str(folders[0]))
