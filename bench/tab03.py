"""Table III (tab:N3V): per-scene PSNR on N3V; NeRF/GS baselines, the experts, MoE-GS N=2,3,4."""

from bench.spec import Claim, Spec, expert, external, moe

_EXPERTS = ["4DGaussians", "E-D3DGS", "STG†", "Ex4DGS"]

SPEC = Spec(
    id="tab03",
    title="Main comparison on N3V (PSNR)",
    dataset="n3v",
    axis="scenes",
    paper="tab03",
    rows=(
        *(
            external(n)
            for n in ("HyperReel", "K-Planes", "MixVoxels-L", "3DGStream", "DASS", "SaRO-GS", "SwinGS")
        ),
        expert("4DGaussians"),
        expert("E-D3DGS"),
        expert("STG†", "STG"),
        expert("Ex4DGS"),
        moe("MoE-GS (N=2)", 2),
        moe("MoE-GS (N=3)", 3),
        moe("MoE-GS (N=4)", 4),
    ),
    claims=(
        Claim(
            "n2-every-scene",
            "MoE-GS (N=2) beats both of its experts (Ex4DGS, STG) on every scene",
            "better",
            {"a": "MoE-GS (N=2)", "b": ["Ex4DGS", "STG†"], "columns": "@scenes"},
            "Table III",
        ),
        Claim(
            "n3-every-scene",
            "MoE-GS (N=3) beats each of its experts on every scene",
            "better",
            {"a": "MoE-GS (N=3)", "b": ["Ex4DGS", "STG†", "E-D3DGS"], "columns": "@scenes"},
            "Table III",
        ),
        Claim(
            "n3-gt-n2",
            "N=3 > N=2 on average",
            "better",
            {"a": "MoE-GS (N=3)", "b": "MoE-GS (N=2)"},
            "Table III",
        ),
        Claim(
            "n4-ge-n3",
            "N=4 >= N=3 on average",
            "better",
            {"a": "MoE-GS (N=4)", "b": "MoE-GS (N=3)", "strict": False},
            "Table III",
        ),
        Claim(
            "moe-best-average",
            "MoE-GS achieves the highest average PSNR",
            "best",
            {"row": "MoE-GS (N=4)", "among": _EXPERTS + ["MoE-GS (N=2)", "MoE-GS (N=3)"]},
            "Sec. VI-B, Quantitative",
        ),
    ),
    motion=True,
    notes="STG† (150-frame split) is one STG model over the preset's frame window. N=2: {Ex4DGS, STG}, "
    "N=3: + E-D3DGS, N=4: + 4DGaussians.",
)

if __name__ == "__main__":
    from bench.all import main_for

    main_for(SPEC.id)
