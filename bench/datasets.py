"""The paper's datasets as the harness sees them: printed scene names, loader names, protocol, stand-in.

Stdlib only (no torch): listing tables never loads data. ``bench.scenes`` turns these into concrete
scenes for a preset (real folder when present, synthetic stand-in otherwise).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bench.spec import by_name


@dataclass(frozen=True)
class Dataset:
    """One benchmark dataset.

    Attributes:
        name: loader prefix in ``moegs.data.load_scene`` (``"n3v"`` -> ``"n3v:coffee_martini"``).
        title: the paper's name for it.
        scenes: printed column name -> loader scene name, in the paper's order. Several printed
            spellings may map to one scene (Table XII prints "Cut Roast Beef").
        stand_in: synthetic scene (``moegs.data.synthetic``) used when no real scene is present.
        paper_protocol: loader keyword arguments of the paper's protocol (resolution, frame window).
        multiview: several cameras per time step.
        expert_config: expert name -> config fields the paper's runs on this dataset change (e.g. STG†
            on N3V); they reach every build of that expert on this dataset's scenes (stand-ins included).
    """

    name: str
    title: str
    scenes: dict[str, str]
    stand_in: str
    paper_protocol: dict = field(default_factory=dict)
    multiview: bool = True
    expert_config: dict = field(default_factory=dict)

    def scene_names(self) -> list[str]:
        """Distinct loader scene names in paper order."""
        return list(dict.fromkeys(self.scenes.values()))

    def column_of(self, scene: str) -> str:
        """The first printed column name of a loader scene name."""
        for column, name in self.scenes.items():
            if name == scene:
                return column
        raise KeyError(f"{self.name}: unknown scene {scene!r}; scenes: {self.scene_names()}")


DATASETS: dict[str, Dataset] = by_name(
    (
        Dataset(
            "n3v",
            "N3V (Neural 3D Video)",
            {
                "Coffee Martini": "coffee_martini",
                "Cook Spinach": "cook_spinach",
                "Cut Roasted Beef": "cut_roasted_beef",
                "Cut Roast Beef": "cut_roasted_beef",
                "Flame Salmon": "flame_salmon",
                "Flame Steak": "flame_steak",
                "Sear Steak": "sear_steak",
            },
            stand_in="n3v_like",
            # 1352x1014, 300 frames, cam00 held out (official_moegs.md section 8)
            paper_protocol={"resolution_scale": 0.5, "frames": (0, 300)},
            # STG† of Tables III/V/XII: MoE-GS's code trains STG on N3V with SH colours and the Ex4DGS
            # rasteriser instead of the feature decoder (official_moegs.md section 8), which also lets
            # it join the volume router and the lifting. Two 150-frame models (frames 0-149 and 150-299:
            # cvsp-lab/MoE-GS README, "Stage 1"), not STG's own 50-frame windows. The optimiser stays
            # STG's Adam: RAdam is stored only for the router stage, the STG† pretraining code is not.
            expert_config={"stg": {"color": "sh", "antialiased": True, "segment_frames": 150}},
        ),
        Dataset(
            "technicolor",
            "Technicolor",
            {
                "Birthday": "birthday",
                "Fabien": "fabien",
                "Painter": "painter",
                "Theater": "theater",
                "Train": "train",
            },
            stand_in="n3v_like",  # closest synthetic layout: forward-facing multi-view rig
            paper_protocol={"resolution_scale": 1.0},  # full 2048x1088, 50-frame windows (loader default)
            # MoE-GS trains STG with SH colours on Technicolor too (scripts_MoE-GS/train_E3_tech.sh ->
            # Pretrained/technicolor/STG_shs; thirdparty/polynomial/scene_tech/oursfull.py)
            expert_config={"stg": {"color": "sh", "antialiased": True}},
        ),
        Dataset(
            "hypernerf",
            "HyperNeRF (vrig)",
            {"3dprinter": "3dprinter", "banana": "peel-banana", "broom": "broom", "chicken": "chicken"},
            stand_in="dnerf_like",  # monocular
            paper_protocol={"resolution_scale": 0.5},
            multiview=False,
        ),
        Dataset(
            "panoptic",
            "PanopticSports",
            {
                "Basketball": "basketball",
                "Boxes": "boxes",
                "Football": "football",
                "Juggle": "juggle",
                "Softball": "softball",
                "Tennis": "tennis",
            },
            stand_in="n3v_like",
            paper_protocol={"resolution_scale": 1.0},  # 640x360, 150 frames
        ),
        Dataset(
            "dnerf",
            "D-NeRF",
            {
                "Bouncingballs": "bouncingballs",
                "Hellwarrior": "hellwarrior",
                "Hook": "hook",
                "Jumpingjacks": "jumpingjacks",
                "Lego": "lego",
                "Mutant": "mutant",
                "Standup": "standup",
                "Trex": "trex",
            },
            stand_in="dnerf_like",
            paper_protocol={"resolution_scale": 1.0},  # 800x800 (dynamic-GS protocol), white background
            multiview=False,
        ),
    ),
    "datasets",
)


def get_dataset(name: str) -> Dataset:
    """A dataset by loader name; ``KeyError`` lists the valid names."""
    if name not in DATASETS:
        raise KeyError(f"unknown dataset {name!r}; valid: {', '.join(DATASETS)}")
    return DATASETS[name]
