"""Scenes by name: ``load_scene("dnerf:mutant")``, ``load_scene("n3v:coffee_martini", frames=(0, 150))``.

A name is ``<dataset>:<scene>``. Real scenes resolve to ``data_root() / <dataset> / <scene folder>``
(``MOEGS_DATA``, default ``../shared/data``); ``path=`` overrides the folder. ``synthetic:<name>``
builds a procedural stand-in through ``moegs.data.synthetic.load_synthetic``. Loaders (and torch) are
imported on first use, so listing datasets and scenes is cheap.

Scene folder lookup is case-insensitive and knows the usual aliases (``technicolor:birthday`` ->
``Birthday``, ``hypernerf:chicken`` -> ``vrig-chicken``, ``hypernerf:broom`` -> ``broom2``).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

from moegs.paths import data_root

if TYPE_CHECKING:
    from torch import Tensor

    from moegs.data.scene import ImageCache, PointCloud, Scene, View

# dataset -> (module, function, file or folder that marks a scene folder, layout description)
_DATASETS: dict[str, tuple[str, str, tuple[str, ...], str]] = {
    "dnerf": (
        "moegs.data.dnerf",
        "load_dnerf",
        ("transforms_train.json",),
        "transforms_{train,val,test}.json + {train,val,test}/r_XXX.png",
    ),
    "panoptic": (
        "moegs.data.panoptic",
        "load_panoptic",
        ("train_meta.json",),
        "train_meta.json, test_meta.json, ims/<cam>/<frame>.jpg (Dynamic3DGaussians)",
    ),
    "n3v": ("moegs.data.n3v", "load_n3v", ("poses_bounds.npy",), "poses_bounds.npy + camXX.mp4"),
    "technicolor": (
        "moegs.data.technicolor",
        "load_technicolor",
        ("colmap_*", "cameras_parameters.txt"),
        "colmap_<frame>/{images,sparse/0} (STG/Ex4DGS) or *_undist_<frame>_<cam>.png + "
        "cameras_parameters.txt",
    ),
    "hypernerf": (
        "moegs.data.hypernerf",
        "load_hypernerf",
        ("dataset.json",),
        "dataset.json, metadata.json, scene.json, camera/<id>.json, rgb/<k>x/<id>.png",
    ),
    "synthetic": ("moegs.data.synthetic", "load_synthetic", (), "procedural, generated on demand"),
}

_ALIASES = {
    "hypernerf": {
        "chicken": ["vrig-chicken", "vrig_chicken"],
        "3dprinter": ["vrig-3dprinter", "vrig_3dprinter"],
        "broom": ["broom2", "vrig-broom", "vrig_broom"],
        "peel-banana": ["vrig-peel-banana", "vrig_peel-banana", "peel_banana", "banana"],
    },
    "n3v": {"flame_salmon": ["flame_salmon_1"], "coffee_martini": ["coffee"]},
}
"""The suite's scene name (what recipes and tables use) -> the other spellings a scene goes by (the
originals' folder names); each is accepted as a name and looked for as a folder."""

__all__ = [
    "ImageCache",
    "PointCloud",
    "Scene",
    "View",
    "canonical_scene",
    "dataset_module",
    "list_datasets",
    "list_scenes",
    "load_scene",
    "resolve_scene_path",
]


def __getattr__(name: str) -> Any:
    """``Scene``, ``View``, ``ImageCache``, ``PointCloud`` of ``moegs.data.scene``, imported on first use."""
    if name in ("ImageCache", "PointCloud", "Scene", "View"):
        from moegs.data import scene

        return getattr(scene, name)
    raise AttributeError(f"module 'moegs.data' has no attribute {name!r}")


def list_datasets() -> list[str]:
    """Dataset names accepted by :func:`load_scene`."""
    return list(_DATASETS)


def dataset_module(dataset: str) -> str:
    """The module that loads ``dataset``'s scenes, e.g. ``"moegs.data.dnerf"`` (named, not imported)."""
    if dataset not in _DATASETS:
        raise ValueError(f"unknown dataset {dataset!r}; valid datasets: {list_datasets()}")
    return _DATASETS[dataset][0]


def parse_scene_name(name: str) -> tuple[str, str]:
    """``(dataset, scene)`` of ``<dataset>:<scene>``; ``ValueError`` naming the valid datasets otherwise."""
    if ":" not in name:
        raise ValueError(f"scene name must be '<dataset>:<scene>', got {name!r}; datasets: {list_datasets()}")
    dataset, scene = name.split(":", 1)
    dataset = dataset.strip().lower()
    if dataset not in _DATASETS:
        raise ValueError(f"unknown dataset {dataset!r} in {name!r}; valid datasets: {list_datasets()}")
    scene = scene.strip()
    if not scene:
        raise ValueError(f"scene name {name!r} has no scene after ':'")
    if "/" in scene or "\\" in scene or scene in (".", ".."):
        raise ValueError(
            f"scene name {name!r}: the part after ':' names a scene folder under MOEGS_DATA/{dataset}/ "
            "(no '/', '\\', '.' or '..')"
        )
    return dataset, scene


def canonical_scene(name: str) -> str:
    """The suite's name of a scene, ``<dataset>:<scene>``, for any spelling the loader accepts:
    ``n3v:flame_salmon_1`` -> ``n3v:flame_salmon`` (scene overrides and tables use it)."""
    dataset, scene = parse_scene_name(name)
    for canonical, others in _ALIASES.get(dataset, {}).items():
        if scene.lower() in (canonical, *others):
            return f"{dataset}:{canonical}"
    return f"{dataset}:{scene.lower()}"


def _is_scene(folder: Path, markers: tuple[str, ...]) -> bool:
    return folder.is_dir() and any(any(folder.glob(m)) for m in markers)


def list_scenes(dataset: str) -> list[str]:
    """Scene folders of ``dataset`` present under the data root (empty if none)."""
    if dataset not in _DATASETS:
        raise ValueError(f"unknown dataset {dataset!r}; valid datasets: {list_datasets()}")
    root = data_root()
    markers = _DATASETS[dataset][2]
    if root is None or not markers or not (root / dataset).is_dir():
        return []
    return sorted(p.name for p in (root / dataset).iterdir() if _is_scene(p, markers))


def resolve_scene_path(name: str) -> Path:
    """Folder of a real scene under the data root; ``FileNotFoundError`` says where it looked and why."""
    dataset, scene = parse_scene_name(name)
    module, _, markers, layout = _DATASETS[dataset]
    if not markers:
        raise ValueError(f"{name!r} is generated, it has no folder")
    root = data_root()
    if root is None:
        raise FileNotFoundError(
            f"{name}: no data root. Set MOEGS_DATA to a folder holding {dataset}/{scene}/ ({layout})"
        )
    base = root / dataset
    canonical = canonical_scene(name).partition(":")[2]
    wanted = list(dict.fromkeys([scene, canonical, *_ALIASES.get(dataset, {}).get(canonical, [])]))
    existing = {p.name.lower(): p for p in base.iterdir()} if base.is_dir() else {}
    for candidate in wanted:
        folder = existing.get(candidate.lower())
        if folder is not None:
            if not _is_scene(folder, markers):
                raise FileNotFoundError(
                    f"{name}: {folder} exists but does not look like a {dataset} scene; expected {layout}"
                )
            return folder
    raise FileNotFoundError(
        f"{name}: expected folder {base / scene} (MOEGS_DATA={root}) with {layout}; "
        f"scenes found there: {list_scenes(dataset) or 'none'}"
    )


def load_scene(
    name: str, path: str | Path | None = None, background: str | Tensor | None = None, **kwargs: Any
) -> Scene:
    """Load a scene by registry name.

    Args:
        name: ``dnerf:<scene>``, ``panoptic:<scene>``, ``n3v:<scene>``, ``technicolor:<scene>``,
            ``hypernerf:<scene>`` or ``synthetic:<name>``.
        path: explicit scene folder (skips the data-root lookup).
        background: ``"white"``, ``"black"`` or RGB ``[3]``: the colour renders and ground truth share.
            D-NeRF composites its RGBA images on it; the other datasets' images are opaque, so it is only
            what renders show where no Gaussian covers a pixel. None: the dataset's default.
        **kwargs: passed to the dataset's loader (``resolution_scale``, ``frames`` ...).
    """
    from moegs.data._io import with_background

    dataset, scene = parse_scene_name(name)
    module_name, fn_name, _, layout = _DATASETS[dataset]
    module = importlib.import_module(module_name)
    loader = getattr(module, fn_name)
    if dataset == "synthetic":  # ``path`` is the parent folder of the generated scenes
        if path is not None:
            kwargs["root"] = path
        if background is not None:
            kwargs["background"] = background
        return loader(scene, **kwargs)
    folder = Path(path) if path is not None else resolve_scene_path(name)
    if not folder.is_dir():
        raise FileNotFoundError(f"{name}: expected folder {folder} with {layout}")
    kwargs.setdefault("name", f"{dataset}:{scene}")
    return with_background(loader, folder, background, **kwargs)
