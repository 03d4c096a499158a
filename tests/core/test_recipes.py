"""Recipes (``moegs.recipes.config_for``) pinned to the original code, row by row.

Each row: what ``config_for(expert, scene, "paper")`` must give for one field, and where the original sets
that value (repository-relative ``file:line`` at the snapshots named in ``specs/experts_*.md``:
4DGaussians 843d5ac, E-D3DGS a68543e, Grid4D c9a93fb, DeformableGS ac42372, STG 427abfc, Ex4DGS 7fac649).
A field holding a scaled value says so (``x 5``: times the hard-coded ``spatial_lr_scale``). STG's
``tgs/`` is ``thirdparty/gaussian_splatting/``.
"""

from __future__ import annotations

import math

import pytest
from helpers.training import builtin_experts

from moegs.experts import get_expert_class
from moegs.recipes import changed_fields, config_for, dataset_of, get_field, override_key, with_fields
from moegs.train.strategy import NEVER

ROWS = [
    # -- DeformableGS (ingra14m/Deformable-3D-Gaussians) ---------------------------------------------
    ("deformable", "dnerf:mutant", "train.iterations", 40_000),  # arguments/__init__.py:81
    ("deformable", "dnerf:mutant", "warm_up", 3000),  # arguments/__init__.py:82
    (
        "deformable",
        "dnerf:mutant",
        "means_lr",
        1.6e-4,
    ),  # arguments/__init__.py:83 (x 5: gaussian_model.py:120)
    ("deformable", "dnerf:mutant", "means_lr_max_steps", 30_000),  # arguments/__init__.py:86
    ("deformable", "dnerf:mutant", "deform_lr_max_steps", 40_000),  # arguments/__init__.py:87
    ("deformable", "dnerf:mutant", "spatial_lr_scale", 5.0),  # scene/gaussian_model.py:117
    ("deformable", "dnerf:mutant", "scales_lr", 5e-3),  # arguments/__init__.py:90 x 5 (gaussian_model.py:124)
    ("deformable", "dnerf:mutant", "train.lambda_dssim", 0.2),  # arguments/__init__.py:93
    ("deformable", "dnerf:mutant", "strategy.densify_from", 500),  # arguments/__init__.py:96
    ("deformable", "dnerf:mutant", "strategy.reset_every", 3000),  # arguments/__init__.py:95
    ("deformable", "dnerf:mutant", "strategy.densify_until", 15_000),  # arguments/__init__.py:97
    ("deformable", "dnerf:mutant", "strategy.densify_every", 100),  # arguments/__init__.py:94
    ("deformable", "dnerf:mutant", "strategy.grad_threshold", 2e-4),  # branch paper: arguments/__init__.py:98
    ("deformable", "dnerf:mutant", "time_freqs", 6),  # utils/time_utils.py:65 (is_blender)
    ("deformable", "dnerf:mutant", "timenet_out", 30),  # utils/time_utils.py:72-78
    ("deformable", "dnerf:mutant", "time_noise", False),  # train.py:96 (no AST with --is_blender)
    ("deformable", "dnerf:mutant", "sh_degree", 3),  # arguments/__init__.py:52
    ("deformable", "hypernerf:chicken", "train.iterations", 20_000),  # README.md:89 --iterations 20000
    ("deformable", "hypernerf:chicken", "time_noise", True),  # train.py:54,96 (AST on real data)
    ("deformable", "hypernerf:chicken", "time_freqs", 10),  # utils/time_utils.py:65
    # -- Grid4D (JiaweiXu8/Grid4D) ----------------------------------------------------------------------
    ("grid4d", "dnerf:mutant", "train.iterations", 50_000),  # arguments/__init__.py:101
    ("grid4d", "dnerf:mutant", "warm_up", 3000),  # arguments/__init__.py:102
    ("grid4d", "dnerf:mutant", "means_lr_max_steps", 35_000),  # arguments/__init__.py:106
    ("grid4d", "dnerf:mutant", "deform_lr_max_steps", 45_000),  # arguments/__init__.py:117
    ("grid4d", "dnerf:mutant", "scales_lr", 5e-3),  # arguments/__init__.py:120 x 5 (gaussian_model.py:124)
    ("grid4d", "dnerf:mutant", "grid_lr_scale", 50.0),  # arguments/dnerf/mutant.py:23
    ("grid4d", "dnerf:mutant", "network_lr_scale", 5.0),  # arguments/dnerf/mutant.py:24
    ("grid4d", "dnerf:mutant", "lambda_spatial", 0.5),  # arguments/dnerf/mutant.py:26
    ("grid4d", "dnerf:mutant", "temporal_perturb", (1e-2, 1e-2, 1e-2, 1e-3)),  # arguments/dnerf/mutant.py:32
    ("grid4d", "dnerf:mutant", "bound", 1.6),  # arguments/dnerf/mutant.py:14
    ("grid4d", "dnerf:mutant", "temporal_desired", (32, 32, 16)),  # arguments/dnerf/mutant.py:11
    ("grid4d", "dnerf:mutant", "depth", 0),  # arguments/dnerf/mutant.py:18
    ("grid4d", "dnerf:mutant", "strategy.reset_every", 3000),  # arguments/__init__.py:125
    ("grid4d", "dnerf:mutant", "strategy.prune_after_reset_only", True),  # scene/gaussian_model.py:374-380
    ("grid4d", "dnerf:lego", "grid_lr_scale", 250.0),  # arguments/dnerf/lego.py:23
    ("grid4d", "dnerf:lego", "lambda_spatial", 1.0),  # arguments/dnerf/lego.py:26
    ("grid4d", "dnerf:lego", "lambda_temporal", 1.0),  # arguments/dnerf/lego.py:30
    ("grid4d", "dnerf:lego", "temporal_perturb", (1e-2, 1e-2, 1e-2, 0.0)),  # arguments/dnerf/lego.py:32
    ("grid4d", "n3v:sear_steak", "bound", 30.0),  # arguments/neu3d/sear_steak.py:14
    ("grid4d", "n3v:sear_steak", "temporal_desired", (512, 512, 128)),  # arguments/neu3d/sear_steak.py:11
    ("grid4d", "n3v:sear_steak", "strategy.densify_every", 400),  # arguments/neu3d/sear_steak.py:40
    ("grid4d", "n3v:sear_steak", "strategy.reset_every", 6000),  # arguments/neu3d/sear_steak.py:41
    ("grid4d", "n3v:sear_steak", "reg_after_densify", True),  # arguments/neu3d/sear_steak.py:42
    (
        "grid4d",
        "n3v:sear_steak",
        "strategy.prune_world_scale",
        None,
    ),  # neu3d/sear_steak.py:36 disable_ws_prune
    ("grid4d", "n3v:sear_steak", "train.iterations", 20_000),  # arguments/neu3d/sear_steak.py:39
    ("grid4d", "n3v:coffee_martini", "temporal_desired", (64, 64, 128)),  # neu3d/coffee_martini.py:11
    ("grid4d", "n3v:coffee_martini", "train.lambda_dssim", 0.0),  # neu3d/coffee_martini.py:36
    ("grid4d", "n3v:coffee_martini", "train.iterations", 50_000),  # arguments/__init__.py:101 (not set)
    ("grid4d", "hypernerf:3dprinter", "bound", 1.0),  # arguments/hypernerf/vrig_3dprinter.py:14
    ("grid4d", "hypernerf:3dprinter", "warm_up", 1000),  # vrig_3dprinter.py:34
    ("grid4d", "hypernerf:3dprinter", "train.iterations", 40_000),  # vrig_3dprinter.py:35
    ("grid4d", "hypernerf:chicken", "strategy.reset_every", 1000),  # vrig_chicken.py:35
    ("grid4d", "hypernerf:peel-banana", "grid_lr_scale", 10.0),  # vrig_peel-banana.py:23
    # -- 4DGaussians (hustvl/4DGaussians) -------------------------------------------------------------
    ("fourdgs", "dnerf:mutant", "coarse_iterations", 3000),  # arguments/dnerf/dnerf_default.py:5
    ("fourdgs", "dnerf:mutant", "train.iterations", 3000 + 20_000),  # dnerf_default.py:5,11
    ("fourdgs", "dnerf:mutant", "means_lr_max_steps", 20_000),  # arguments/__init__.py:119
    ("fourdgs", "dnerf:mutant", "deformation_lr_final", 1.6e-6),  # dnerf_default.py:7
    ("fourdgs", "dnerf:mutant", "grid_lr_final", 1.6e-5),  # dnerf_default.py:10
    ("fourdgs", "dnerf:mutant", "strategy.prune_every", 8000),  # dnerf_default.py:12
    ("fourdgs", "dnerf:mutant", "strategy.reset_every", 3000),  # arguments/__init__.py:136
    ("fourdgs", "dnerf:mutant", "time_resolution", 75),  # arguments/dnerf/mutant.py:8
    ("fourdgs", "dnerf:mutant", "train.lambda_dssim", 0.0),  # arguments/__init__.py:131
    ("fourdgs", "dnerf:mutant", "plane_tv_weight", 1e-4),  # dnerf_default.py:27
    ("fourdgs", "dnerf:mutant", "time_smoothness_weight", 1e-2),  # dnerf_default.py:28
    ("fourdgs", "dnerf:mutant", "width", 64),  # dnerf_default.py:26
    ("fourdgs", "dnerf:mutant", "max_init_points", 2000),  # scene/dataset_readers.py:330
    ("fourdgs", "n3v:cook_spinach", "train.iterations", 3000 + 14_000),  # arguments/dynerf/default.py:24,26
    ("fourdgs", "n3v:cook_spinach", "train.batch_size", 2),  # arguments/dynerf/cook_spinach.py:3
    ("fourdgs", "n3v:coffee_martini", "train.batch_size", 4),  # arguments/dynerf/default.py:25 (inherited)
    ("fourdgs", "n3v:flame_salmon", "train.batch_size", 4),  # arguments/dynerf/default.py:25 (inherited)
    ("fourdgs", "n3v:cook_spinach", "strategy.densify_until", 10_000),  # arguments/dynerf/default.py:27
    ("fourdgs", "n3v:cook_spinach", "strategy.reset_every", 60_000),  # arguments/dynerf/default.py:28
    ("fourdgs", "n3v:cook_spinach", "deform_opacity", True),  # arguments/dynerf/default.py:14 (no_do)
    ("fourdgs", "n3v:cook_spinach", "deform_sh", True),  # arguments/dynerf/default.py:15 (no_dshs)
    ("fourdgs", "n3v:cook_spinach", "time_resolution", 150),  # arguments/dynerf/default.py:6
    ("fourdgs", "n3v:cook_spinach", "feature_dim", 16),  # arguments/dynerf/default.py:5
    ("fourdgs", "n3v:cook_spinach", "width", 128),  # arguments/dynerf/default.py:10
    ("fourdgs", "n3v:cook_spinach", "strategy.batch_stats", "summed"),  # train.py:195-196, 223-225, 262
    ("fourdgs", "n3v:cook_spinach", "time_smoothness_weight", 1e-3),  # arguments/dynerf/default.py:12
    ("fourdgs", "hypernerf:chicken", "time_resolution", 80),  # arguments/hypernerf/chicken.py:7
    ("fourdgs", "hypernerf:peel-banana", "time_resolution", 250),  # arguments/hypernerf/banana.py:7
    ("fourdgs", "hypernerf:chicken", "multires", (1, 2, 4)),  # arguments/hypernerf/default.py:8
    ("fourdgs", "hypernerf:chicken", "train.batch_size", 2),  # arguments/hypernerf/default.py:19
    ("fourdgs", "hypernerf:chicken", "strategy.reset_every", 300_000),  # arguments/hypernerf/default.py:22
    # -- E-D3DGS (JeongminB/E-D3DGS) ------------------------------------------------------------------
    ("ed3dgs", "n3v:cook_spinach", "train.iterations", 80_000),  # arguments/dynerf/default.py:21
    ("ed3dgs", "n3v:cook_spinach", "strategy.densify_from", 5000),  # arguments/dynerf/default.py:24
    ("ed3dgs", "n3v:cook_spinach", "strategy.grad_threshold", 3e-4),  # arguments/dynerf/default.py:27-28
    ("ed3dgs", "n3v:cook_spinach", "strategy.densify_until", 80_000),  # arguments/dynerf/default.py:33
    ("ed3dgs", "n3v:cook_spinach", "strategy.reset_every", NEVER),  # arguments/__init__.py:125 (6e6)
    ("ed3dgs", "n3v:cook_spinach", "deform_from", 5000),  # arguments/dynerf/default.py:14
    ("ed3dgs", "n3v:cook_spinach", "coarse_to_fine_until", 10_000),  # arguments/dynerf/default.py:13
    ("ed3dgs", "n3v:cook_spinach", "lambda_ssim", 1.0),  # arguments/dynerf/default.py:37
    ("ed3dgs", "n3v:cook_spinach", "multiview_ssim_iters", 5),  # arguments/dynerf/default.py:38
    ("ed3dgs", "n3v:cook_spinach", "smoothness_reg", 1.0),  # arguments/dynerf/default.py:40
    ("ed3dgs", "n3v:cook_spinach", "width", 128),  # arguments/dynerf/default.py:7
    ("ed3dgs", "n3v:cook_spinach", "strategy.batch_stats", "summed"),  # train.py:204-206, 250
    ("ed3dgs", "hypernerf:chicken", "strategy.batch_stats", "summed"),  # train.py:204-206, 250
    ("stg", "n3v:cook_spinach", "strategy.batch_stats", "last"),  # train.py:257-258
    ("ed3dgs", "n3v:flame_steak", "strategy.grad_threshold", 2e-4),  # arguments/dynerf/flame_steak.py:4-5
    ("ed3dgs", "technicolor:birthday", "min_embeddings", 5),  # arguments/technicolor/default.py:13
    ("ed3dgs", "technicolor:birthday", "max_embeddings", 25),  # arguments/technicolor/default.py:14
    ("ed3dgs", "technicolor:birthday", "coarse_to_fine_until", None),  # technicolor/default.py:19
    (
        "ed3dgs",
        "technicolor:birthday",
        "deform",
        ("means", "scales", "quats", "opacities"),
    ),  # default.py:9-11
    ("ed3dgs", "technicolor:birthday", "deformation_lr", 1.6e-3),  # arguments/technicolor/default.py:50
    ("ed3dgs", "technicolor:birthday", "random_until", 60_000),  # arguments/technicolor/default.py:73
    ("ed3dgs", "technicolor:birthday", "strategy.densify_from", 500),  # arguments/technicolor/default.py:35
    ("ed3dgs", "technicolor:birthday", "train.iterations", 100_000),  # arguments/technicolor/Birthday.py:3
    ("ed3dgs", "technicolor:birthday", "smoothness_reg", 0.1),  # arguments/technicolor/Birthday.py:9
    ("ed3dgs", "technicolor:train", "deformation_lr", 5e-3),  # arguments/technicolor/Train.py:3
    ("ed3dgs", "technicolor:train", "train.iterations", 120_000),  # arguments/technicolor/Train.py:7
    ("ed3dgs", "hypernerf:chicken", "min_embeddings", 16),  # arguments/hypernerf/vrig-chicken.py:3
    ("ed3dgs", "hypernerf:chicken", "train.iterations", 60_000),  # arguments/hypernerf/vrig-chicken.py:11
    ("ed3dgs", "hypernerf:chicken", "strategy.grad_threshold", 2e-4),  # arguments/hypernerf/default.py:29-30
    ("ed3dgs", "hypernerf:chicken", "temporal_tv", 1e-4),  # arguments/hypernerf/default.py:62
    ("ed3dgs", "hypernerf:chicken", "train.batch_size", 2),  # arguments/hypernerf/default.py:22
    ("ed3dgs", "hypernerf:chicken", "consecutive_pairs", True),  # default.py:2 loader nerfies; train.py:110
    ("ed3dgs", "n3v:coffee_martini", "consecutive_pairs", False),  # train.py:114-125 (multi-view sampler)
    # -- STG (oppo-us-research/SpacetimeGaussians) --------------------------------------------------------
    (
        "stg",
        "n3v:cook_spinach",
        "train.iterations",
        25_000,
    ),  # configs/n3d_full/cook_spinach.json:6 (test_iteration)
    ("stg", "n3v:cook_spinach", "means_lr_max_steps", 30_000),  # tgs/arguments/__init__.py:94-98
    ("stg", "n3v:cook_spinach", "scales_lr", 1.5e-3),  # configs/n3d_full/cook_spinach.json:4
    ("stg", "n3v:cook_spinach", "strategy.max_densify_events", 6),  # tgs/arguments/__init__.py:121
    ("stg", "n3v:cook_spinach", "strategy.densify_until", 9000),  # tgs/arguments/__init__.py:118
    ("stg", "n3v:cook_spinach", "strategy.reset_at", (3000, 6000)),  # helper_train.py:217-218
    ("stg", "n3v:cook_spinach", "strategy.prune_z_below", 4.5),  # train.py:149-152; helper_train.py:223-226
    ("stg", "n3v:cook_spinach", "strategy.omega_mask_from", 8001),  # helper_train.py:196-199
    ("stg", "n3v:cook_spinach", "strategy.bbox_prune_at", 10_000),  # helper_train.py:227-228
    ("stg", "n3v:cook_spinach", "strategy.guided_from", 1600),  # tgs/arguments/__init__.py:128-129
    ("stg", "n3v:cook_spinach", "train.lambda_dssim", 0.2),  # tgs/arguments/__init__.py:113
    ("stg", "n3v:coffee_martini", "train.iterations", 10_000),  # configs/n3d_full/coffee_martini.json:6
    ("stg", "n3v:coffee_martini", "scales_lr", 3e-3),  # configs/n3d_full/coffee_martini.json:4
    ("stg", "n3v:coffee_martini", "strategy.prune_until", 9000),  # helper_train.py:248-252 (densify 2)
    ("stg", "n3v:flame_salmon", "train.iterations", 12_000),  # configs/n3d_full/flame_salmon_1.json:6
    ("stg", "technicolor:birthday", "scales_lr", 5e-3),  # configs/techni_full/Birthday.json:4
    ("stg", "technicolor:birthday", "trbf_scale_init", -2.0),  # configs/techni_full/Birthday.json:5
    ("stg", "technicolor:birthday", "strategy.max_densify_events", 12),  # configs/techni_full/Birthday.json:9
    ("stg", "technicolor:birthday", "decoder_activation", "clamp"),  # configs/techni_full/Birthday.json:11
    ("stg", "technicolor:birthday", "strategy.prune_z_below", None),  # helper_train.py:260-282 (mode 3)
    ("stg", "technicolor:birthday", "thin_later_frames", True),  # configs/techni_full/Birthday.json:6 (3)
    ("stg", "technicolor:theater", "thin_later_frames", True),  # configs/techni_full/Theater.json:6 (3)
    ("stg", "technicolor:train", "thin_later_frames", True),  # configs/techni_full/Train.json:6 (3)
    ("stg", "technicolor:fabien", "thin_later_frames", False),  # configs/techni_full/Fabien.json:6 (0)
    ("stg", "technicolor:painter", "thin_later_frames", False),  # configs/techni_full/Painter.json:6 (0)
    ("stg", "n3v:cook_spinach", "thin_later_frames", False),  # configs/n3d_full/cook_spinach.json:5 (0)
    # -- Ex4DGS (juno181/Ex4DGS) ------------------------------------------------------------------------
    ("ex4dgs", "n3v:cook_spinach", "train.iterations", 40_000),  # configs/N3V/n3v_base.json:15
    ("ex4dgs", "n3v:cook_spinach", "near", 4.0),  # configs/N3V/n3v_base.json:16
    ("ex4dgs", "n3v:cook_spinach", "far", 300.0),  # configs/N3V/n3v_base.json:17
    ("ex4dgs", "technicolor:fabien", "far", 100.0),  # configs/techni/Fabien.json:14
    ("ex4dgs", "technicolor:theater", "far", 100.0),  # configs/techni/Theater.json:14
    ("ex4dgs", "technicolor:birthday", "far", 300.0),  # configs/techni/Birthday.json:14
    ("ex4dgs", "n3v:cook_spinach", "strategy.prune_from", 6000),  # arguments/__init__.py:127
    ("ex4dgs", "n3v:cook_spinach", "strategy.grad_threshold", 2e-4),  # configs/N3V/n3v_base.json:3
    ("ex4dgs", "n3v:cook_spinach", "strategy.dynamic_grad_threshold", 1e-4),  # configs/N3V/n3v_base.json:4
    ("ex4dgs", "n3v:cook_spinach", "strategy.densify_every", 300),  # configs/N3V/n3v_base.json:18
    ("ex4dgs", "n3v:cook_spinach", "make_dynamic_interval", 100),  # configs/N3V/n3v_base.json:27
    ("ex4dgs", "n3v:cook_spinach", "strategy.error_prune_from", NEVER),  # c_gaussian_model.py:830-872
    ("ex4dgs", "n3v:cook_spinach", "strategy.reset_every", NEVER),  # reset_opacity is never called
    ("ex4dgs", "n3v:cook_spinach", "motion_opacities_lr", 0.01),  # configs/N3V/n3v_base.json:22
    ("ex4dgs", "n3v:cook_spinach", "optimizer", "radam"),  # scene/c_gaussian_model.py:449
    ("ex4dgs", "n3v:cook_spinach", "time_pad", 2),  # configs/N3V/n3v_base.json:13
    ("ex4dgs", "technicolor:birthday", "time_pad", 3),  # configs/techni/Birthday.json:9
    ("ex4dgs", "technicolor:birthday", "strategy.densify_every", 250),  # configs/techni/Birthday.json:15
    ("ex4dgs", "technicolor:birthday", "extract_every", 1777),  # configs/techni/Birthday.json:25
    ("ex4dgs", "technicolor:painter", "train.iterations", 30_000),  # configs/techni/Painter.json:12
    ("ex4dgs", "n3v:cook_spinach", "motion_sh0_lr", 2.5e-3),  # arguments/__init__.py:106
    ("ex4dgs", "technicolor:fabien", "motion_sh0_lr", 2.5e-3),  # Fabien.json leaves the default
    ("ex4dgs", "technicolor:birthday", "motion_sh0_lr", 2.5e-4),  # configs/techni/Birthday.json:20
    ("ex4dgs", "technicolor:painter", "motion_shN_lr", 2.5e-4 / 20),  # Painter.json:20 (/20: :441)
    ("ex4dgs", "technicolor:train", "motion_sh0_lr", 2.5e-4),  # configs/techni/Train.json:20
    ("ex4dgs", "technicolor:train", "extract_percentile", 0.99),  # configs/techni/Train.json:27
]

BACKGROUNDS = [
    ("deformable", "dnerf:mutant", "black"),  # arguments/__init__.py:57; no -w in README.md:83
    ("grid4d", "dnerf:mutant", "black"),  # arguments/__init__.py:56; README.md:39
    ("fourdgs", "dnerf:mutant", "white"),  # _white_background store_true, always on
    ("fourdgs", "n3v:cook_spinach", "white"),
    ("ed3dgs", "n3v:cook_spinach", "white"),  # arguments/__init__.py:54; train.py:46
    ("stg", "n3v:cook_spinach", "black"),  # tgs/arguments/__init__.py:69; train.py:91
    ("ex4dgs", "n3v:cook_spinach", "white"),  # render.py:131 (evaluation)
    ("mode", "n3v:cook_spinach", "white"),  # arguments_MoDE/__init__.py
]


def _close(a, b) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return a is not None and b is not None and math.isclose(a, b, rel_tol=1e-9)
    return a == b


@pytest.mark.parametrize(("expert", "scene", "field", "expected"), ROWS)
def test_paper_recipe_matches_the_original(expert, scene, field, expected):
    value = get_field(config_for(expert, scene, "paper").config, field)
    value = tuple(value) if isinstance(value, list) else value
    assert _close(value, expected), (
        f"{expert} on {scene}: {field} = {value!r}, the original uses {expected!r}"
    )


@pytest.mark.parametrize(("expert", "scene", "background"), BACKGROUNDS)
def test_background_is_the_originals(expert, scene, background):
    recipe = config_for(expert, scene, "paper")
    assert recipe.background == background and recipe.load_kwargs["background"] == background


@pytest.mark.parametrize("expert", builtin_experts())
@pytest.mark.parametrize(
    "scene", ["dnerf:mutant", "n3v:coffee_martini", "technicolor:train", "hypernerf:chicken"]
)
def test_quick_differs_only_in_its_named_fields(expert, scene):
    """The quick recipe is the paper recipe reduced by the documented quick fields, and nothing else."""
    paper, quick = config_for(expert, scene, "paper"), config_for(expert, scene, "quick")
    named = set(quick.reductions)
    differ = set(changed_fields(paper.config, quick.config))
    assert differ <= named, f"{expert} on {scene}: quick also changes {sorted(differ - named)}"
    assert quick.base == paper.base and quick.scene_overrides == paper.scene_overrides
    assert quick.config.train.iterations < paper.config.train.iterations


@pytest.mark.parametrize(
    ("expert", "alias", "scene"),
    [
        ("grid4d", "n3v:flame_salmon_1", "n3v:flame_salmon"),  # the original N3V folder's name
        ("stg", "n3v:coffee", "n3v:coffee_martini"),
        ("grid4d", "hypernerf:vrig-broom", "hypernerf:broom"),
        ("ed3dgs", "hypernerf:banana", "hypernerf:peel-banana"),
    ],
)
def test_scene_overrides_follow_every_spelling_of_a_scene(expert, alias, scene):
    expected = config_for(expert, scene).scene_overrides
    assert expected and config_for(expert, alias).scene_overrides == expected


def test_override_key_is_the_dataset_and_the_suites_spelling():
    """One resolution for the experts' scene overrides and the router's per-scene rates."""
    assert override_key("n3v:flame_salmon_1") == ("n3v", "n3v:flame_salmon")
    assert override_key("technicolor:Fabien") == ("technicolor", "technicolor:fabien")
    assert override_key("synthetic:n3v_like") == ("n3v", "n3v:n3v_like")  # a stand-in: its layout
    assert override_key("synthetic:n3v_like", "technicolor") == ("technicolor", "technicolor:n3v_like")
    assert override_key("my_scene", "dnerf") == ("dnerf", "dnerf:my_scene")  # built by hand: as typed
    with pytest.raises(ValueError, match="unknown synthetic scene 'nosuch'"):
        override_key("synthetic:nosuch")


def test_dataset_presets_and_adaptations():
    assert config_for("grid4d", "n3v:sear_steak").base == "paper-n3v"
    assert not config_for("grid4d", "n3v:sear_steak").adapted
    panoptic = config_for("grid4d", "panoptic:basketball")
    assert panoptic.adapted and panoptic.base == "paper-n3v" and "adaptation" in panoptic.base_source
    assert config_for("ed3dgs", "technicolor:fabien").base == "paper-technicolor"
    # stand-ins take the recipe of their layout's dataset, or the dataset the harness says
    assert dataset_of("synthetic:n3v_like") == "n3v" and dataset_of("synthetic:dnerf_like") == "dnerf"
    assert config_for("ed3dgs", "synthetic:n3v_like", dataset="technicolor").base == "paper-technicolor"


def test_world_frame_rules_stay_on_their_dataset():
    """STG's z < 4.5 prune and Ex4DGS's near plane 4 hold in real N3V's world frame only."""
    assert config_for("stg", "n3v:sear_steak").config.strategy.prune_z_below == 4.5
    stand_in = config_for("stg", "synthetic:n3v_like")
    assert stand_in.config.strategy.prune_z_below is None and stand_in.frame_overrides
    assert config_for("stg", "panoptic:basketball").config.strategy.prune_z_below is None
    assert config_for("ex4dgs", "synthetic:n3v_like").config.near == 0.2  # the code's default
    assert config_for("ex4dgs", "n3v:sear_steak").config.near == 4.0


def test_quick_loads_real_scenes_at_its_resolution_and_stand_ins_at_their_own():
    """A stand-in is generated at its preset's size; only a user's resolution applies to it."""
    real = config_for("grid4d", "dnerf:mutant", "quick")
    scale = real.config.train.resolution_scale
    assert (
        scale is not None
        and scale < 1
        and real.load_kwargs == {"background": "black", "resolution_scale": scale}
    )
    stand_in = config_for("grid4d", "synthetic:dnerf_like", "quick")
    assert stand_in.config.train.resolution_scale == scale and stand_in.load_kwargs == {"background": "black"}
    mine = config_for("grid4d", "synthetic:dnerf_like", "quick", overrides={"train.resolution_scale": 0.5})
    assert mine.load_kwargs == {"background": "black", "resolution_scale": 0.5}


@pytest.mark.parametrize(("expert", "scene"), [("static", "dnerf:mutant"), ("fourdgs", "n3v:coffee_martini")])
def test_quick_moves_the_sh_band_interval_to_the_same_fraction_of_its_run(expert, scene):
    """3DGS: one band per 1000 of 30k iterations; at quick's 600, one per 20."""
    paper = config_for(expert, scene, "paper").config.train
    quick = config_for(expert, scene, "quick").config.train
    assert quick.sh_degree_interval == max(
        1, round(paper.sh_degree_interval * quick.iterations / paper.iterations)
    )
    assert quick.sh_degree_interval < paper.sh_degree_interval
    if expert == "static":
        assert (paper.sh_degree_interval, paper.iterations, quick.sh_degree_interval) == (1000, 30_000, 20)


def test_overrides_apply_last_and_are_recorded():
    recipe = config_for("grid4d", "dnerf:lego", "quick", overrides={"train.iterations": 7, "depth": 1})
    assert recipe.config.train.iterations == 7 and recipe.config.depth == 1
    assert recipe.config.grid_lr_scale == 250.0  # the scene override survives the quick reduction
    record = recipe.provenance()
    assert record["scene_overrides"]["grid_lr_scale"] == 250.0 and record["overrides"]["depth"] == 1
    assert record["reductions"]["train.iterations"] == 600


def test_steps_name_every_stage_that_changed_the_config():
    recipe = config_for("grid4d", "dnerf:lego", "quick", overrides={"depth": 1})
    steps = recipe.steps
    assert steps[0] == "dnerf preset 'paper-dnerf' (" + recipe.base_source + ")"
    assert steps[1].startswith("scene overrides: ") and "grid_lr_scale=250.0" in steps[1]
    assert steps[2].startswith("quick reductions: ") and "train.iterations=600" in steps[2]
    assert steps[3:] == ["user overrides: depth=1", "background: black"]
    assert config_for("grid4d", "dnerf:mutant", "paper").steps[1:] == ["background: black"]


def test_bad_names_fail_clearly():
    with pytest.raises(ValueError, match="unknown recipe preset 'fast'"):
        config_for("grid4d", "dnerf:mutant", "fast")
    with pytest.raises(KeyError, match="has no field 'widht'"):
        config_for("grid4d", "dnerf:mutant", overrides={"widht": 3})
    with pytest.raises(ValueError, match="unknown expert 'nosuch'"):
        config_for("nosuch", "dnerf:mutant")
    with pytest.raises(ValueError, match="<dataset>:<scene>"):
        config_for("grid4d", "mutant")


def test_with_fields_rebuilds_nested_configs_once():
    cls = get_expert_class("fourdgs").config_class
    config = cls.from_preset("paper")
    # FourDGSConfig checks that its strategy's coarse stage matches its own: both change in one go
    changed = with_fields(config, {"coarse_iterations": 10, "strategy.coarse_iterations": 10})
    assert changed.coarse_iterations == changed.strategy.coarse_iterations == 10
    assert config.coarse_iterations == 3000  # the input is untouched


def test_recipes_carry_the_originals_loader_arguments():
    """Real N3V: E-D3DGS drops cam13 on coffee_martini (its README.md:43) and resizes with Lanczos, as do
    4DGaussians and Grid4D; Ex4DGS bilinear; STG keeps the loader's bicubic. Each starts from its own
    initial cloud at ``paper`` (``quick`` takes whichever the folder has). Stand-ins take none. The
    arguments reach load_scene through the recipe and through a run's recorded config.json."""
    from moegs.recipes import scene_load_kwargs

    coffee = config_for("ed3dgs", "n3v:coffee_martini", "paper")
    assert coffee.loader_args == {"resample": "lanczos", "points": "mvs100k", "exclude": ("cam13",)}
    assert coffee.load_kwargs["exclude"] == ("cam13",) and coffee.load_kwargs["resample"] == "lanczos"
    quick = config_for("ed3dgs", "n3v:sear_steak", "quick").loader_args
    assert quick == {"resample": "lanczos", "points": "auto"}
    assert config_for("fourdgs", "n3v:sear_steak", "paper").loader_args == {
        "resample": "lanczos",
        "points": "mvs40k",
    }
    assert config_for("grid4d", "n3v:sear_steak", "paper").loader_args == {
        "resample": "lanczos",
        "points": "mvs40k",
    }
    assert config_for("ex4dgs", "n3v:sear_steak", "paper").loader_args == {
        "resample": "bilinear",
        "points": "sparse",
    }
    assert config_for("stg", "n3v:sear_steak", "paper").loader_args == {"points": "frames"}
    # Technicolor: load_technicolor(points=...) with the same names (E-D3DGS scene/dataset_readers.py:352;
    # STG dataset_readers.py:913-932; Ex4DGS scene/dataset_readers.py:492-501)
    assert config_for("stg", "technicolor:birthday", "paper").loader_args == {"points": "frames"}
    assert config_for("ex4dgs", "technicolor:birthday", "paper").loader_args == {"points": "sparse"}
    assert config_for("ed3dgs", "technicolor:birthday", "paper").loader_args == {"points": "mvs100k"}
    for expert in ("stg", "ex4dgs", "ed3dgs"):
        assert config_for(expert, "technicolor:birthday", "quick").loader_args == {"points": "auto"}
    assert config_for("ed3dgs", "synthetic:n3v_like", "quick").loader_args == {}
    recorded = coffee.provenance()["loader_args"]
    assert recorded == {"resample": "lanczos", "points": "mvs100k", "exclude": ["cam13"]}  # JSON: a list
    reloaded = scene_load_kwargs(coffee.scene, coffee.background, 0.5, False, loader_args=recorded)
    assert reloaded == {
        "background": "white",
        "resolution_scale": 0.5,
        "resample": "lanczos",
        "points": "mvs100k",
        "exclude": ("cam13",),
    }
    assert "loader arguments: resample='lanczos', points='mvs100k', exclude=('cam13',)" in coffee.steps
