"""Table VIII (tab:KD_MoE): experts retrained with the GT loss vs distilled from MoE-GS (N=3)."""

from bench.spec import QUALITY, Claim, Spec, distill, expert

_PAIRS = (("E-D3DGS", "E-D3DGS (Distilled)"), ("STG", "STG (Distilled)"), ("Ex4DGS", "Ex4DGS (Distilled)"))

SPEC = Spec(
    id="tab08",
    title="Distilled vs retrained experts (Technicolor)",
    dataset="technicolor",
    axis="metrics",
    metrics=QUALITY,
    rows=tuple(r for e, d in _PAIRS for r in (expert(e), distill(d, e, weighted=True))),
    claims=tuple(
        Claim(
            f"distill-{e.lower()}" + ("" if m == "PSNR" else f"-{m.lower()}"),
            f"{d} outperforms the retrained {e} ({m})",
            "better",
            {"a": d, "b": e, "metric": m, "columns": [m]},
            "Sec. IV-C (ii), Table VIII",
        )
        for e, d in _PAIRS
        for m in QUALITY
    ),
    notes="Teacher: MoE-GS N=3 {Ex4DGS, STG, E-D3DGS} with the volume-aware pixel router; students use the "
    "routing-weighted KD loss ('Distilled (Ours)' of Table XV).",
)
