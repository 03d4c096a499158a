"""Table XVII (tab:dnerf_large_motion): D-NeRF, DeformableGS, Grid4D and MoE-GS N=2."""

from bench.spec import Claim, Spec, beats_every_scene, beats_on_average, expert, moe

SPEC = Spec(
    id="tab17",
    title="Large motion: D-NeRF (PSNR)",
    dataset="dnerf",
    rows=(expert("DeformableGS"), expert("Grid4D"), moe("MoE-GS (N=2)", ("deformable", "grid4d"))),
    claims=(
        beats_every_scene("n2-every-scene", "MoE-GS (N=2)", ["DeformableGS", "Grid4D"], "Appendix"),
        beats_on_average("n2-best-average", "MoE-GS (N=2)", ["DeformableGS", "Grid4D"], "Appendix"),
        Claim(
            "grid4d-beats-deformable",
            "Grid4D beats DeformableGS on average",
            "better",
            {"a": "Grid4D", "b": "DeformableGS"},
            "Table XVII",
        ),
    ),
    motion=True,
    notes="The metric is not printed; PSNR assumed. Mutant is the staged real scene.",
)

if __name__ == "__main__":
    from bench.all import main_for

    main_for(SPEC.id)
