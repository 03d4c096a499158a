"""Table XVIII (tab:abl_train_budget): expert training budget 100/50/20/10 %, experts and MoE-GS N=3."""

from bench.spec import Claim, Spec, expert, moe

_BUDGETS = {"100%": 1.0, "50%": 0.5, "20%": 0.2, "10%": 0.1}
_EXPERTS = ["E-D3DGS", "STG", "4DGaussians"]
_MOE = "MoE-GS (N=3)"

SPEC = Spec(
    id="tab18",
    title="Expert training budget (N3V)",
    dataset="n3v",
    axis="budgets",
    budgets=_BUDGETS,
    columns=tuple(_BUDGETS),
    rows=(*(expert(e) for e in _EXPERTS), moe(_MOE, 3)),
    claims=(
        Claim(
            "moe-beats-experts-every-budget",
            "MoE-GS beats every expert at every budget",
            "better",
            {"a": _MOE, "b": _EXPERTS, "columns": list(_BUDGETS)},
            "Table XVIII",
        ),
        Claim(
            "budget-monotone",
            "Less training budget never improves PSNR (0.05 dB tolerance)",
            "monotone",
            {"rows": [*_EXPERTS, _MOE], "columns": list(_BUDGETS), "tolerance": 0.05},
            "Table XVIII",
        ),
    ),
    notes="Budget = fraction of each expert's training iterations (the paper: wall-clock time); MoE-GS at "
    "budget b uses experts trained with budget b and a full router schedule. Metric and dataset "
    "inferred (PSNR, N3V).",
)
