"""Figure specs: the paper's figures that are drawn from data, as rows x columns like the tables.

Each figure names a plot in ``bench.plots`` and claims checked on its values. Only the static-ROI
numbers are printed by the paper (in the text, ``tables/paper/text/static_roi.json``); the other
figures have claims but no published numbers.
"""

from __future__ import annotations

from bench.spec import EXPERTS, MOE_SETS, Claim, Row, Spec, expert, mode_family, moe

_FOUR = ("4DGaussians", "STG", "E-D3DGS", "Ex4DGS")  # the four experts of Fig. 1 and Fig. motion_pattern


def _trajectory(name: str, **params) -> Row:
    return Row(name, "trajectory", params)


def _gates_figure(fid: str, dataset: str, what: str, experts: list[str], source: str) -> Spec:
    """Gate maps, each expert's render, the blend and the ground truth of one test view (the router of
    the table over ``experts`` on ``dataset``: the same build, so no extra training)."""
    row = f"MoE-GS (N={len(experts)}) gates"
    return Spec(
        id=fid,
        title=f"Router gate maps, expert renders and the blend ({what})",
        dataset=dataset,
        figure=True,
        plot="gates",
        metrics=("Gate experts", "PSNR"),
        rows=(Row(row, "gates", {"experts": experts, "router": "vapr"}),),
        claims=(
            Claim(
                "spatially-adaptive",
                "Routing is spatially adaptive: >= 2 experts lead >= 5% of pixels",
                "at_least",
                {"rows": [row], "threshold": 2, "metric": "Gate experts"},
                source,
            ),
        ),
    )


FIGURES: tuple[Spec, ...] = (
    Spec(
        id="fig01",
        title="Fig. 1: no single expert wins everywhere (scene / spatial / temporal)",
        dataset="n3v",
        figure=True,
        plot="limitations",
        metrics=("PSNR", "Winners", "Switches"),
        rows=(
            *(expert(e) for e in _FOUR),
            Row("Best-expert analysis", "bestmap", {"experts": [EXPERTS[e] for e in _FOUR]}),
        ),
        claims=(
            Claim(
                "scene-level",
                "(a) The best expert differs between scenes",
                "differs_across",
                {"rows": list(_FOUR)},
                "Fig. 1a",
            ),
            Claim(
                "spatial-level",
                "(b) At least two experts each win >= 5% of the pixels of a view",
                "at_least",
                {"rows": ["Best-expert analysis"], "threshold": 2, "metric": "Winners"},
                "Fig. 1b",
            ),
            Claim(
                "temporal-level",
                "(c) The best expert changes over time at least once",
                "at_least",
                {"rows": ["Best-expert analysis"], "threshold": 1, "metric": "Switches"},
                "Fig. 1c",
            ),
        ),
    ),
    _gates_figure("fig_gates", "n3v", "Fig. n3v_qualitative", list(MOE_SETS[3]), "Sec. IV-C, Qualitative"),
    _gates_figure(
        "fig_gates_dnerf",
        "dnerf",
        "Table XVII's MoE-GS, real D-NeRF",
        ["deformable", "grid4d"],
        "ours: Sec. IV-C's qualitative claim on D-NeRF (the paper shows no gate maps there)",
    ),
    _gates_figure(
        "fig_gates_panoptic",
        "panoptic",
        "Table XVI's MoE-GS, real Panoptic",
        ["fourdgs", "grid4d"],
        "ours: Sec. IV-C's qualitative claim on Panoptic (the paper shows no gate maps there)",
    ),
    Spec(
        id="fig_trajectories",
        title="Expert-specific motion trajectories (Figs. motion_pattern, motion 1-3)",
        dataset="n3v",
        axis="metrics",
        figure=True,
        plot="trajectories",
        metrics=("Coherence", "Curvature", "Speed"),
        rows=tuple(_trajectory(e, expert=EXPERTS[e]) for e in _FOUR),
        claims=(
            Claim(
                "4dgs-coherent",
                "4DGaussians trajectories are more spatially coherent than Ex4DGS's",
                "better",
                {"a": "4DGaussians", "b": "Ex4DGS", "metric": "Coherence", "columns": ["Coherence"]},
                "Appendix, Analysis of Expert-Specific Motion Behavior",
            ),
            Claim(
                "ed3dgs-coherent",
                "E-D3DGS trajectories are more spatially coherent than Ex4DGS's",
                "better",
                {"a": "E-D3DGS", "b": "Ex4DGS", "metric": "Coherence", "columns": ["Coherence"]},
                "Appendix, Analysis of Expert-Specific Motion Behavior",
            ),
            Claim(
                "stg-smooth",
                "STG trajectories have lower curvature than Ex4DGS's",
                "better",
                {"a": "STG", "b": "Ex4DGS", "metric": "Curvature", "columns": ["Curvature"]},
                "Appendix, Analysis of Expert-Specific Motion Behavior",
            ),
            Claim(
                "ed3dgs-fast",
                "E-D3DGS trajectories are faster than 4DGaussians'",
                "better",
                {"a": "E-D3DGS", "b": "4DGaussians", "metric": "Speed", "columns": ["Speed"]},
                "Appendix, Analysis of Expert-Specific Motion Behavior",
            ),
        ),
        notes="Coherence: mean cosine similarity of displacements of k-nearest canonical neighbours; "
        "curvature: mean turning angle between successive steps; speed: mean path length per unit time.",
    ),
    Spec(
        id="fig_mode_motion",
        title="MoDE increases per-Gaussian motion flexibility (Fig. mode_motion)",
        dataset="n3v",
        axis="metrics",
        figure=True,
        plot="trajectories",
        metrics=("Coherence", "Speed"),
        rows=(
            _trajectory("4DGaussians", expert="fourdgs"),
            _trajectory("MoDE (4DGaussians w/ E-D3DGS)", mode=["fourdgs", "ed3dgs"]),
        ),
        claims=(
            Claim(
                "mode-flexible",
                "MoDE trajectories are less rigidly coherent than 4DGaussians'",
                "better",
                {
                    "a": "4DGaussians",
                    "b": "MoDE (4DGaussians w/ E-D3DGS)",
                    "metric": "Coherence",
                    "columns": ["Coherence"],
                },
                "Sec. IV-D (i)",
            ),
        ),
    ),
    Spec(
        id="fig_mdc",
        title="Multi-view depth consistency of experts and lifted MoE-GS (Fig. MDC_ana)",
        dataset="n3v",
        figure=True,
        plot="mdc",
        metrics=("MDC",),
        rows=(
            *(Row(e, "mdc", {"expert": EXPERTS[e]}) for e in _FOUR),
            Row("MoE-GS (N=3, lifted)", "mdc", {"experts": list(MOE_SETS[3]), "router": "vapr"}),
        ),
        claims=(
            Claim(
                "moe-lowest-mdc",
                "MoE-GS has the lowest MDC error",
                "best",
                {
                    "row": "MoE-GS (N=3, lifted)",
                    "among": list(_FOUR),
                    "metric": "MDC",
                    "columns": "@scenes",
                    "strict": True,
                },
                "Sec. IV-D (i)",
            ),
        ),
    ),
    Spec(
        id="fig_static_roi",
        title="Static expert: static-ROI quality, +E-D3DGS vs +3DGS-MCMC (Fig. static_expert)",
        dataset="n3v",
        figure=True,
        plot="paper_vs_ours",
        paper="static_roi",
        metrics=("PSNR static", "SSIM static", "PSNR"),
        scenes=("coffee_martini", "flame_salmon"),
        rows=(moe("MoE-GS (N=3)", 3), moe("MoE-GS (N=3)*", ("ex4dgs", "stg", "mcmc"))),
        claims=(
            Claim(
                "static-psnr",
                "+3DGS-MCMC improves static-ROI PSNR",
                "better",
                {"a": "MoE-GS (N=3)*", "b": "MoE-GS (N=3)", "metric": "PSNR static", "columns": "@scenes"},
                "Sec. IV-C (iv)",
            ),
            Claim(
                "static-ssim",
                "+3DGS-MCMC improves static-ROI SSIM",
                "better",
                {"a": "MoE-GS (N=3)*", "b": "MoE-GS (N=3)", "metric": "SSIM static", "columns": "@scenes"},
                "Sec. IV-C (iv)",
            ),
        ),
        notes="The paper uses fixed detail-rich static ROIs on Coffee Martini and Flame Salmon; here the ROI "
        "is the scene's static mask (synthetic ground truth), and real N3V scenes need a mask file.",
    ),
    Spec(
        id="fig_mode_tradeoff",
        title="E-D3DGS-based MoDE: dynamic-region gain vs static-region loss (Fig. mode_abl)",
        dataset="n3v",
        axis="metrics",
        figure=True,
        plot="paper_vs_ours",
        metrics=("PSNR dynamic", "PSNR static", "PSNR"),
        rows=mode_family("E-D3DGS", "4DGaussians", "Grid4D"),
        claims=(
            *(
                Claim(
                    f"dynamic-gain{suffix}",
                    f"E-D3DGS w/ {member} improves the dynamic region over E-D3DGS",
                    "better",
                    {
                        "a": f"E-D3DGS w/ {member}",
                        "b": "E-D3DGS",
                        "metric": "PSNR dynamic",
                        "columns": ["PSNR dynamic"],
                    },
                    "Sec. IV-B",
                )
                for member, suffix in (("4DGaussians", ""), ("Grid4D", "-grid4d"))
            ),
            Claim(
                "static-loss",
                "... and degrades static regions",
                "better",
                {
                    "a": "E-D3DGS",
                    "b": ["E-D3DGS w/ 4DGaussians", "E-D3DGS w/ Grid4D"],
                    "metric": "PSNR static",
                    "columns": ["PSNR static"],
                },
                "Sec. IV-B",
            ),
        ),
    ),
)
