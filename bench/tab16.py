"""Table XVI (tab:panoptic_large_motion): PanopticSports, 4DGaussians, Grid4D and MoE-GS N=2."""

from bench.spec import moe_pair_spec

SPEC = moe_pair_spec(
    "tab16",
    "Large motion: PanopticSports (PSNR)",
    "panoptic",
    ("4DGaussians", "Grid4D"),
    ("Appendix, Large-Motion Benchmarks", "Appendix, Large-Motion Benchmarks"),
    notes="The metric is not printed; PSNR assumed. Basketball is the staged real scene, shipped here "
    "without init_pt_cld.npz (the originals' initialisation): the loader triangulates SIFT matches of the "
    "training cameras at the window's first frame with the given calibration instead "
    "(moegs.data.triangulate, about 2.3k points where the first frames match). Four held-out cameras: "
    "the report's PSNR per held-out camera shows when one camera's failure moves the mean. The test "
    "cameras have no seg/ masks, so there is no dynamic-region score.",
)
