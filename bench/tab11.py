"""Table XI (tab:tradeoff): MoDE vs MoE-GS, PSNR and training time."""

from bench.spec import Claim, Spec, expert, mode, moe

_BASE, _M_ED, _M_GRID, _MOE = "4DGaussians", "4DGaussians w/ E-D3DGS", "4DGaussians w/ Grid4D", "MoE-GS (N=2)"
_VARIANTS = ((_M_ED, ""), (_M_GRID, "-grid4d"))  # each MoDE row and its claims' id suffix

SPEC = Spec(
    id="tab11",
    title="MoDE vs MoE-GS: quality and training cost (N3V)",
    dataset="n3v",
    axis="metrics",
    metrics=("PSNR", "Time"),
    column_metric={"Train Time (h)": "Time"},
    rows=(
        expert(_BASE),
        mode(_M_ED, "4DGaussians", "E-D3DGS"),
        mode(_M_GRID, "4DGaussians", "Grid4D"),
        moe(_MOE, 2),
    ),
    claims=(
        *(
            Claim(
                f"mode-improves{suffix}",
                f"MoDE ({row}) improves PSNR over the single-deformation baseline",
                "better",
                {"a": row, "b": _BASE, "columns": ["PSNR"]},
                "Sec. IV-D (ii)",
            )
            for row, suffix in _VARIANTS
        ),
        Claim(
            "moe-larger-gain",
            "MoE-GS gains substantially more PSNR than MoDE",
            "better",
            {"a": _MOE, "b": [_M_ED, _M_GRID], "columns": ["PSNR"]},
            "Sec. IV-D (ii)",
        ),
        Claim(
            "mode-modest-cost",
            "MoDE costs more training time than the baseline",
            "better",
            {"a": _BASE, "b": [_M_ED, _M_GRID], "metric": "Time", "columns": ["Train Time (h)"]},
            "Sec. IV-D (ii)",
            kind="sanity",  # MoDE trains the baseline's fields and a second deformation
        ),
        *(
            Claim(
                f"moe-highest-cost{suffix}",
                f"MoE-GS costs considerably more training time than MoDE ({row})",
                "better",
                {"a": row, "b": _MOE, "metric": "Time", "columns": ["Train Time (h)"]},
                "Sec. IV-D (ii)",
                kind="sanity",  # MoE-GS trains two experts and a router
            )
            for row, suffix in _VARIANTS
        ),
    ),
    notes="Train time in hours of wall clock on the machine of the run (the paper's are GPU hours); MoE-GS "
    "counts its experts' training plus router training.",
)
