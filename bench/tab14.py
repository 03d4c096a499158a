"""Table XIV (tab:monocular): monocular HyperNeRF, 4DGaussians, E-D3DGS and MoE-GS N=2."""

from bench.spec import Spec, beats_every_scene, beats_on_average, expert, moe

SPEC = Spec(
    id="tab14",
    title="Monocular HyperNeRF (PSNR)",
    dataset="hypernerf",
    rows=(expert("4DGaussians"), expert("E-D3DGS"), moe("MoE-GS (N=2)", ("fourdgs", "ed3dgs"))),
    claims=(
        beats_every_scene("n2-every-scene", "MoE-GS (N=2)", ["4DGaussians", "E-D3DGS"], "Table XIV"),
        beats_on_average("n2-best-average", "MoE-GS (N=2)", ["4DGaussians", "E-D3DGS"], "Appendix"),
    ),
    motion=True,
    notes="The paper does not print the two experts of MoE-GS (N=2); {4DGaussians, E-D3DGS} (the listed "
    "baselines) is assumed.",
)

if __name__ == "__main__":
    from bench.all import main_for

    main_for(SPEC.id)
