"""Table I (tab:comparison): MoDE vs MoE-GS design trade-offs, printed as symbols (no numbers).

Nothing to compute: the LaTeX reproduces the paper's symbols and points at the tables whose numbers
bear on each row (training efficiency: Table XI; specialisation: Tables II and X).
"""

from bench.spec import Row, Spec

_ROWS = (
    "Direct Gaussian-level 3D reconstruction",
    "Compatibility with non-canonical deformations",
    "Training stability",
    "Training efficiency",
    "Expert specialization flexibility",
)

SPEC = Spec(
    id="tab01",
    title="MoDE vs MoE-GS design trade-offs (qualitative)",
    dataset="",
    axis="none",
    metrics=(),
    rows=tuple(
        Row(r, "qualitative", {"evidence": e})
        for r, e in zip(
            _ROWS,
            (
                "design property (MoDE deforms one shared set of Gaussians; MoE-GS blends images)",
                "design property (MoDE needs canonical-deformation experts)",
                "tab09 (seed spread)",
                "tab11 (training time)",
                "tab02, tab10 (expert sets)",
            ),
            strict=True,
        )
    ),
    notes="Categorical table; values are the paper's symbols, not computed.",
)
