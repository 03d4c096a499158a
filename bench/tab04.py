"""Table IV (tab:technicolor): per-scene PSNR on Technicolor; baselines, experts and MoE-GS N=3."""

from bench.spec import Claim, Spec, beats_every_scene, expert, external, moe

_EXPERTS = ["4DGaussians", "STG", "E-D3DGS", "Ex4DGS"]

SPEC = Spec(
    id="tab04",
    title="Main comparison on Technicolor (PSNR)",
    dataset="technicolor",
    rows=(external("DyNeRF"), external("HyperReel"), *(expert(n) for n in _EXPERTS), moe("MoE-GS (N=3)", 3)),
    claims=(
        beats_every_scene("n3-every-scene", "MoE-GS (N=3)", ["STG", "E-D3DGS", "Ex4DGS"], "Table IV"),
        Claim(
            "moe-best-average",
            "MoE-GS achieves the highest average PSNR",
            "best",
            {"row": "MoE-GS (N=3)", "among": ["DyNeRF", "HyperReel", *_EXPERTS]},
            "Sec. IV-C, Quantitative",
        ),
    ),
)
