"""Table III (tab:N3V): per-scene PSNR on N3V; NeRF/GS baselines, the experts, MoE-GS N=2,3,4."""

from bench.spec import Claim, Spec, beats_every_scene, beats_on_average, expert, external, moe

_EXPERTS = ["4DGaussians", "E-D3DGS", "STG†", "Ex4DGS"]
_BASELINES = ("HyperReel", "K-Planes", "MixVoxels-L", "3DGStream", "DASS", "SaRO-GS", "SwinGS")

SPEC = Spec(
    id="tab03",
    title="Main comparison on N3V (PSNR)",
    dataset="n3v",
    rows=(
        *(external(n) for n in _BASELINES),
        expert("4DGaussians"),
        expert("E-D3DGS"),
        expert("STG†", "STG"),
        expert("Ex4DGS"),
        moe("MoE-GS (N=2)", 2),
        moe("MoE-GS (N=3)", 3),
        moe("MoE-GS (N=4)", 4),
    ),
    claims=(
        beats_every_scene("n2-every-scene", "MoE-GS (N=2)", ["Ex4DGS", "STG†"], "Table III"),
        beats_every_scene("n3-every-scene", "MoE-GS (N=3)", ["Ex4DGS", "STG†", "E-D3DGS"], "Table III"),
        beats_on_average("n3-gt-n2", "MoE-GS (N=3)", ["MoE-GS (N=2)"], "Table III"),
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
            {"row": "MoE-GS (N=4)", "among": [*_BASELINES, *_EXPERTS, "MoE-GS (N=2)", "MoE-GS (N=3)"]},
            "Sec. IV-C, Quantitative",
        ),
    ),
    motion=True,
    notes="STG† trains one model per 150 frames (moegs.train.segments); the CPU presets' frame windows "
    "are one segment. N=2: {Ex4DGS, STG}, "
    "N=3: + E-D3DGS, N=4: + 4DGaussians.",
)
