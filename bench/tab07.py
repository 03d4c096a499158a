"""Table VII (tab:abl_render_prune): single-pass multi-expert rendering and gate-aware pruning."""

from bench.spec import EFFICIENCY, Claim, Spec, moe

_NONE, _NO_SP, _NO_PR, _FULL = ("w/o Single-Pass & Pruning", "w/o Single-Pass", "w/o Pruning", "MoE-GS (N=3)")

SPEC = Spec(
    id="tab07",
    title="Ablation of single-pass rendering and pruning (N=3, N3V)",
    dataset="n3v",
    axis="metrics",
    metrics=EFFICIENCY,
    rows=(
        moe(_NONE, 3, single_pass=False),
        moe(_NO_SP, 3, single_pass=False, prune="gate"),
        moe(_NO_PR, 3),
        moe(_FULL, 3, prune="gate"),
    ),
    claims=(
        Claim(
            "single-pass-fps",
            "Single-pass rendering raises FPS with pruning",
            "better",
            {"a": _FULL, "b": _NO_SP, "metric": "FPS", "columns": ["FPS"]},
            "Sec. IV-C (ii)",
        ),
        Claim(
            "single-pass-fps-unpruned",
            "Single-pass rendering raises FPS without pruning",
            "better",
            {"a": _NO_PR, "b": _NONE, "metric": "FPS", "columns": ["FPS"]},
            "Sec. IV-C (ii)",
        ),
        Claim(
            "single-pass-same-image",
            "Single-pass rendering does not change the image (PSNR equal)",
            "within",
            {"a": _FULL, "b": _NO_SP, "tolerance": 0.01, "columns": ["PSNR"]},
            "Table VII",
            kind="sanity",  # an implementation check: one pass composites what separate passes do
        ),
        Claim(
            "full-best-fps",
            "The full configuration renders fastest ('significant improvements in FPS')",
            "best",
            {
                "row": _FULL,
                "among": [_NONE, _NO_SP, _NO_PR],
                "metric": "FPS",
                "columns": ["FPS"],
                "strict": True,
            },
            "Sec. IV-C (ii)",
        ),
        Claim(
            "full-best-memory",
            "The full configuration uses the least memory (ties with w/o Single-Pass, which prunes too)",
            "best",
            {"row": _FULL, "among": [_NONE, _NO_SP, _NO_PR], "metric": "Memory", "columns": ["Memory"]},
            "Sec. IV-C (ii)",
            kind="sanity",  # the pruned model is the smallest
        ),
        Claim(
            "pruning-memory",
            "Pruning lowers memory",
            "better",
            {"a": _FULL, "b": _NO_PR, "metric": "Memory", "columns": ["Memory"]},
            "Sec. IV-C (ii)",
            kind="sanity",  # fewer Gaussians, less memory
        ),
        Claim(
            "pruning-keeps-psnr",
            "Pruning maintains reconstruction quality (no drop > 0.3 dB)",
            "better",
            {"a": _FULL, "b": _NO_PR, "strict": False, "margin": 0.3, "columns": ["PSNR"]},
            "Sec. IV-C (ii)",
        ),
    ),
    notes="Dataset not printed (N3V inferred). 'Pruning' is gate-aware pruning with the library's default "
    "threshold schedule; the ratio is not printed.",
)
