"""Table XIV (tab:monocular): monocular HyperNeRF, 4DGaussians, E-D3DGS and MoE-GS N=2."""

from bench.spec import Claim, Spec, expert, moe

SPEC = Spec(
    id="tab14",
    title="Monocular HyperNeRF (PSNR)",
    dataset="hypernerf",
    axis="scenes",
    paper="tab14",
    rows=(expert("4DGaussians"), expert("E-D3DGS"), moe("MoE-GS (N=2)", ("fourdgs", "ed3dgs"))),
    claims=(
        Claim(
            "n2-every-scene",
            "MoE-GS (N=2) beats both experts on every scene",
            "better",
            {"a": "MoE-GS (N=2)", "b": ["4DGaussians", "E-D3DGS"], "columns": "@scenes"},
            "Table XIV",
        ),
        Claim(
            "n2-best-average",
            "MoE-GS (N=2) has the best average",
            "better",
            {"a": "MoE-GS (N=2)", "b": ["4DGaussians", "E-D3DGS"]},
            "Appendix",
        ),
    ),
    motion=True,
    notes="The paper does not print the two experts of MoE-GS (N=2); {4DGaussians, E-D3DGS} (the listed "
    "baselines) is assumed.",
)

if __name__ == "__main__":
    from bench.all import main_for

    main_for(SPEC.id)
