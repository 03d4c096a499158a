"""Table V (tab:n23-tfm): efficiency of MoE-GS N=2 with gate-aware pruning (PSNR, FPS, memory)."""

from bench.spec import EFFICIENCY, Claim, Spec, expert, moe

_N2, _P55, _P75 = "MoE-GS (N=2)", "MoE-GS (55% pruning)", "MoE-GS (75% pruning)"

SPEC = Spec(
    id="tab05",
    title="Efficiency of MoE-GS N=2 and gate-aware pruning (N3V)",
    dataset="n3v",
    axis="metrics",
    metrics=EFFICIENCY,
    unpruned=_N2,
    rows=(
        expert("STG†", "STG"),
        expert("Ex4DGS"),
        moe(_N2, 2),
        moe(_P55, 2, prune=0.55),
        moe(_P75, 2, prune=0.75),
    ),
    claims=(
        Claim(
            "n2-beats-experts",
            "N=2 outperforms both individual experts in PSNR",
            "better",
            {"a": _N2, "b": ["STG†", "Ex4DGS"], "columns": ["PSNR"]},
            "Sec. IV-C, Quantitative",
        ),
        Claim(
            "prune-fps",
            "Pruning raises FPS (75% > 55% > none)",
            "order",
            {"rows": [_P75, _P55, _N2], "metric": "FPS", "columns": ["FPS"]},
            "Table V",
        ),
        Claim(
            "prune-memory",
            "Pruning lowers memory (75% < 55% < none)",
            "order",
            {"rows": [_P75, _P55, _N2], "metric": "Memory", "columns": ["Memory"]},
            "Table V",
            kind="sanity",  # fewer Gaussians, less memory
        ),
        *(
            Claim(
                f"prune-keeps-psnr{suffix}",
                f"Pruning preserves reconstruction quality ({ratio}: within 0.5 dB, our tolerance)",
                "within",
                {"a": row, "b": _N2, "tolerance": 0.5, "columns": ["PSNR"]},
                "Sec. IV-C, Quantitative",
            )
            for row, ratio, suffix in ((_P75, "75%", ""), (_P55, "55%", "-55"))
        ),
        *(
            Claim(
                f"n2-costs-more-{m.lower()}-{key}",
                f"N=2 costs more than {e} ({m}): 'higher inference and memory cost'",
                "better",
                {"a": e, "b": _N2, "metric": m, "columns": [m]},
                "Sec. IV-C, Quantitative",
                kind="sanity",  # N=2 holds and renders both experts
            )
            for e, key in (("STG†", "stg"), ("Ex4DGS", "ex4dgs"))
            for m in ("FPS", "Memory")
        ),
    ),
    notes="Memory is the size of the rendered model's parameters in MB (the paper does not print the "
    "unit). FPS follows moegs.metrics.speed (median over views, warm-up, device named).",
)
