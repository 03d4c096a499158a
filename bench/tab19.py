"""Table XIX (tab:distill_weight): routing-weighted vs unweighted distillation of E-D3DGS."""

from bench.spec import QUALITY, Claim, Spec, distill, expert

_ROWS = ["Routing Weight (Ours)", "w/o Weight", "E-D3DGS (Baseline)"]

SPEC = Spec(
    id="tab19",
    title="Routing-weighted distillation of E-D3DGS (Technicolor)",
    dataset="technicolor",
    axis="metrics",
    metrics=QUALITY,
    column_metric={"PSNR (dB)": "PSNR"},
    rows=(
        expert("E-D3DGS (Baseline)", "E-D3DGS"),
        distill("w/o Weight", "E-D3DGS", weighted=False),
        distill("Routing Weight (Ours)", "E-D3DGS", weighted=True),
    ),
    claims=(
        Claim(
            "weighted-order-psnr",
            "routing-weighted > unweighted > baseline (PSNR)",
            "order",
            {"rows": _ROWS, "columns": ["PSNR (dB)"]},
            "Appendix, Distillation Weighting Strategies (weighted > unweighted); Table XIX (the rest)",
        ),
        Claim(
            "weighted-order-ssim",
            "routing-weighted > unweighted > baseline (SSIM)",
            "order",
            {"rows": _ROWS, "metric": "SSIM", "columns": ["SSIM"]},
            "Appendix, Distillation Weighting Strategies (weighted > unweighted); Table XIX (the rest)",
        ),
        Claim(
            "weighted-best-lpips",
            "routing-weighted distillation has the lowest LPIPS",
            "best",
            {"row": _ROWS[0], "among": _ROWS, "metric": "LPIPS", "columns": ["LPIPS"]},
            "Table XIX",
        ),
    ),
)
