"""Table XVI (tab:panoptic_large_motion): PanopticSports, 4DGaussians, Grid4D and MoE-GS N=2."""

from bench.spec import Claim, Spec, expert, moe

SPEC = Spec(
    id="tab16",
    title="Large motion: PanopticSports (PSNR)",
    dataset="panoptic",
    axis="scenes",
    paper="tab16",
    rows=(expert("4DGaussians"), expert("Grid4D"), moe("MoE-GS (N=2)", ("fourdgs", "grid4d"))),
    claims=(
        Claim(
            "n2-every-scene",
            "MoE-GS (N=2) consistently outperforms both experts (every scene)",
            "better",
            {"a": "MoE-GS (N=2)", "b": ["4DGaussians", "Grid4D"], "columns": "@scenes"},
            "Appendix",
        ),
        Claim(
            "n2-best-average",
            "MoE-GS (N=2) has the best average",
            "better",
            {"a": "MoE-GS (N=2)", "b": ["4DGaussians", "Grid4D"]},
            "Appendix",
        ),
    ),
    motion=True,
    notes="The metric is not printed; PSNR assumed. Basketball is the staged real scene.",
)

if __name__ == "__main__":
    from bench.all import main_for

    main_for(SPEC.id)
