"""Table XVII (tab:dnerf_large_motion): D-NeRF, DeformableGS, Grid4D and MoE-GS N=2."""

from bench.spec import Claim, moe_pair_spec

SPEC = moe_pair_spec(
    "tab17",
    "Large motion: D-NeRF (PSNR)",
    "dnerf",
    ("DeformableGS", "Grid4D"),
    ("Appendix, Large-Motion Benchmarks", "Appendix, Large-Motion Benchmarks"),
    claims=(
        Claim(
            "grid4d-beats-deformable",
            "Grid4D beats DeformableGS on average",
            "better",
            {"a": "Grid4D", "b": "DeformableGS"},
            "Table XVII",
        ),
    ),
    notes="The metric is not printed; PSNR assumed. Mutant is the staged real scene.",
)
