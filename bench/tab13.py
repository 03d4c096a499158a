"""Table XIII (tab:appen_tech_quanti): per-scene PSNR/SSIM/LPIPS on Technicolor, MoE-GS N=3."""

from bench.spec import QUALITY, Claim, Spec, expert, external, moe

_ROWS = ["DyNeRF", "HyperReel", "4DGaussians", "STG", "Ex4DGS"]

SPEC = Spec(
    id="tab13",
    title="Per-scene PSNR/SSIM/LPIPS on Technicolor",
    dataset="technicolor",
    metrics=QUALITY,
    rows=(
        external("DyNeRF"),
        external("HyperReel"),
        expert("4DGaussians"),
        expert("STG"),
        expert("Ex4DGS"),
        moe("MoE-GS (N=3)", 3),
    ),
    claims=tuple(
        Claim(
            f"n3-best-average-{m.lower()}",
            f"MoE-GS (N=3) has the highest average {m}",
            "best",
            {"row": "MoE-GS (N=3)", "among": _ROWS, "metric": m, "strict": True},
            "Appendix, Quantitative results",
        )
        for m in QUALITY
    ),
    notes="The N=3 set is {Ex4DGS, STG, E-D3DGS}; the table has no E-D3DGS row.",
)
