"""Table XIV (tab:monocular): monocular HyperNeRF, 4DGaussians, E-D3DGS and MoE-GS N=2."""

from bench.spec import moe_pair_spec

SPEC = moe_pair_spec(
    "tab14",
    "Monocular HyperNeRF (PSNR)",
    "hypernerf",
    ("4DGaussians", "E-D3DGS"),
    ("Table XIV", "Table XIV"),
    notes="The paper does not print the two experts of MoE-GS (N=2) here; {4DGaussians, E-D3DGS} (the "
    "listed baselines) is assumed. Its default N=2 set is {Ex4DGS, STG} ('unless otherwise specified', "
    "Sec. IV-C), which this table's rows do not list.",
)
