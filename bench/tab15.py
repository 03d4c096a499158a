"""Table XV (tab:distillation_ablation): retrained vs distilled w/o weight vs distilled (routing weight)."""

from bench.spec import QUALITY, Claim, Row, Spec, distill, expert

_EXPERTS = ("E-D3DGS", "STG", "Ex4DGS")
_RT, _WO, _OURS = "Retrained (GT Loss)", "Distilled (w/o Weight)", "Distilled (Ours)"


def _rows(e: str) -> tuple[Row, ...]:
    return (
        expert(f"{e} / {_RT}", e),
        distill(f"{e} / {_WO}", e, weighted=False),
        distill(f"{e} / {_OURS}", e, weighted=True),
    )


SPEC = Spec(
    id="tab15",
    title="Distillation ablation per scene (Technicolor)",
    dataset="technicolor",
    metrics=QUALITY,
    rows=tuple(r for e in _EXPERTS for r in _rows(e)),
    claims=tuple(
        Claim(
            f"ours-best-{e.lower()}",
            f"{e}: routing-weighted distillation beats retraining and unweighted distillation on average",
            "better",
            {"a": f"{e} / {_OURS}", "b": [f"{e} / {_RT}", f"{e} / {_WO}"]},
            "Appendix, Table XV",
        )
        for e in _EXPERTS
    ),
)
