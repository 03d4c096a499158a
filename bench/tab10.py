"""Table X (expert_pool_ablation): which third expert to add to {Ex4DGS, STG}.

``python -m bench.all --tables 10 --candidate NAME`` adds any registered expert (a plugin's entry-point
name, README "Add your own expert") as one more third-expert row, marked as not in the paper: the spec
declares that extension itself (``Spec.candidates``).
"""

import dataclasses

from bench.spec import Claim, Spec, moe

_N2 = "MoE-GS (N=2)"
_THIRD = {"+ E-D3DGS": "ed3dgs", "+ Grid4D": "grid4d", "+ DeformableGS": "deformable", "+ 3DGS-MCMC": "mcmc"}
_COL = ["PSNR (dB)"]


def with_candidates(spec: Spec, names: tuple[str, ...]) -> Spec:
    """Table X with one more row per candidate expert, ``+ <name>`` over {Ex4DGS, STG}, and the claim that
    it improves over N=2 (ours only: the paper has no such row)."""
    rows = tuple(moe(f"+ {n}", ("ex4dgs", "stg", n), variant=True) for n in names)
    claims = tuple(
        Claim(
            f"n3-beats-n2-candidate-{n}",
            f"N=3 with candidate '{n}' improves over N=2",
            "better",
            {"a": f"+ {n}", "b": _N2, "columns": _COL},
            "candidate expert (not in the paper)",
        )
        for n in names
    )
    return dataclasses.replace(spec, rows=spec.rows + rows, claims=spec.claims + claims)


SPEC = Spec(
    id="tab10",
    title="Expert candidate ablation (N3V)",
    dataset="n3v",
    axis="metrics",
    column_metric={"PSNR (dB)": "PSNR"},
    rows=(moe(_N2, 2), *(moe(name, ("ex4dgs", "stg", key)) for name, key in _THIRD.items())),
    claims=(
        *(
            Claim(
                f"n3-beats-n2-{key}",
                f"N=3 variant '{name}' improves over N=2",
                "better",
                {"a": name, "b": _N2, "columns": _COL},
                "Sec. IV-C (iv)",
                twin=key != "mcmc",  # the static expert's "limited contribution to dynamic regions"
            )
            for name, key in _THIRD.items()
        ),
        Claim(
            "ed3dgs-beats-mcmc",
            "+ E-D3DGS beats + 3DGS-MCMC on the full image (the static expert adds little where things move)",
            "better",
            {"a": "+ E-D3DGS", "b": "+ 3DGS-MCMC", "columns": _COL},
            "Sec. IV-C (iv)",
        ),
        Claim(
            "deformation-order",
            "Among deformation experts: E-D3DGS > Grid4D > DeformableGS",
            "order",
            {"rows": ["+ E-D3DGS", "+ Grid4D", "+ DeformableGS"], "columns": _COL},
            "Sec. IV-C (iv)",
        ),
    ),
    motion=True,
    notes="3DGS-MCMC is a static expert (one model per frame in the library's 'mcmc' expert).",
    candidates=with_candidates,
)
