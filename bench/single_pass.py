"""Single pass against separate renders, timed in pairs: K experts rendered by one ``rasterize_multi`` and
by K ``rasterize`` calls, back to back in one process, round after round.

    python -m bench.single_pass --backend cuda --json reports/gpu/single_pass.json --readme docs/speed.md

pytest-benchmark (``bench.rasterizer``) times each mode in its own test, one after the other, so when the
machine drifts between the two tests (GPU clocks, other load) the ratio of their medians drifts with it:
two H100 runs of the same code read 1.71x and 1.31x at 300k/1024², each with a narrow spread inside its
test. Here every round times both modes back to back, alternating which goes first, and the speed-up is
the median of the per-round ratios (separate / single), with their 10-90% range.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path

import torch

from bench.raster_cases import case_renderer, run_once
from bench.rasterizer import SINGLE_PASS_TARGET
from bench.results import write_json_atomic
from moegs.cli_types import non_negative_int, positive_int
from moegs.metrics.speed import _describe as describe_device  # the suite's device wording

DEFAULT_SIZES = ((5_000, 128), (100_000, 512), (300_000, 1024))


def paired_times(
    single: Callable[[], None],
    separate: Callable[[], None],
    rounds: int,
    warmup: int,
    clock: Callable[[], float] = time.perf_counter,
) -> tuple[list[float], list[float]]:
    """Milliseconds of ``single()`` and ``separate()`` per round; even rounds run single first, odd rounds
    separate first. Each callable must return only when its work is done (synchronised)."""
    if rounds < 1 or warmup < 0:
        raise ValueError(f"paired_times: need rounds >= 1 and warmup >= 0, got {rounds} and {warmup}")
    for _ in range(warmup):
        single()
        separate()
    times: dict[str, list[float]] = {"single": [], "separate": []}
    calls = {"single": single, "separate": separate}
    for r in range(rounds):
        for mode in ("single", "separate") if r % 2 == 0 else ("separate", "single"):
            start = clock()
            calls[mode]()
            times[mode].append(1000 * (clock() - start))
    return times["single"], times["separate"]


def summarise(single_ms: list[float], separate_ms: list[float]) -> dict:
    """Medians of both modes and the per-round speed-up (separate / single): median, 10% and 90%."""
    ratios = [b / a for a, b in zip(single_ms, separate_ms, strict=True)]
    deciles = statistics.quantiles(ratios, n=10, method="inclusive") if len(ratios) > 1 else ratios * 9
    return {
        "single_ms": statistics.median(single_ms),
        "separate_ms": statistics.median(separate_ms),
        "speedup": statistics.median(ratios),
        "speedup_p10": deciles[0],
        "speedup_p90": deciles[-1],
        "rounds": len(ratios),
    }


def measure(
    n: int, res: int, *, backend: str, backward: bool, experts: int, rounds: int, warmup: int
) -> dict:
    """Paired timing of one case (``bench.raster_cases``: ``experts`` x ``n`` Gaussians at ``res``²)."""
    device = "cuda" if backend == "cuda" else "cpu"
    case = dict(n=n, res=res, backend=backend, backward=backward, experts=experts, device=device)
    one, frame_one = case_renderer(**case, single_pass=True)
    many, frame_many = case_renderer(**case, single_pass=False)
    single_ms, separate_ms = paired_times(
        lambda: run_once(one, frame_one, backward),
        lambda: run_once(many, frame_many, backward),
        rounds,
        warmup,
    )
    return {
        **case,
        **summarise(single_ms, separate_ms),
        "single_all_ms": single_ms,
        "separate_all_ms": separate_ms,
    }


def markdown(result: dict, repeats: Sequence[dict] = ()) -> str:
    """The README table of one run (``result["cases"]``, ``result["device"]``, ...); each of ``repeats``
    (other runs of the same cases) adds a column with its median speed-up."""
    again = [{(c["n"], c["res"], c["backward"]): c["speedup"] for c in other["cases"]} for other in repeats]
    again_head = "".join(f" speed-up, run {k + 2} |" for k in range(len(repeats)))
    lines = [
        f"| K = {result['experts']} experts, paired rounds | three `rasterize` (ms) | one `rasterize_multi` "
        f"(ms) | speed-up, median of rounds | 10-90% of rounds |{again_head} target |",
        "|---|---|---|---|---|" + "---|" * len(repeats) + "---|",
    ]
    for c in result["cases"]:
        mode = "fwd+bwd (training)" if c["backward"] else "fwd (rendering)"
        others = [run.get((c["n"], c["res"], c["backward"])) for run in again]
        target = "none (router training step)"
        if not c["backward"]:
            missed = [x for x in [c["speedup"], *others] if x is not None and x < SINGLE_PASS_TARGET]
            target = f"≥ {SINGLE_PASS_TARGET}× (median): {'MISSED' if missed else 'met'}"
        spread = f"{c['speedup_p10']:.2f}-{c['speedup_p90']:.2f}×"
        again_cells = "".join(" – |" if x is None else f" {x:.2f}× |" for x in others)
        lines.append(
            f"| {c['n'] // 1000}k each, {c['res']}², {mode} | {c['separate_ms']:.1f} | "
            f"{c['single_ms']:.1f} | {c['speedup']:.2f}× | {spread} |{again_cells} {target} |"
        )
    runs = f"{1 + len(repeats)} runs, the first one's times" if repeats else "one run"
    lines += [
        "",
        f"`python -m bench.single_pass --backend {result['backend']}` ({runs}): {result['rounds']} rounds "
        f"per case after {result['warmup']} warm-up pairs, the two modes back to back in alternating order; "
        f"{result['device']}; {result['date']}, torch {result['torch']}.",
    ]
    return "\n".join(lines)


def parse_sizes(text: str) -> list[tuple[int, int]]:
    """``"5000:128,100000:512"`` -> ``[(5000, 128), (100000, 512)]``."""
    try:
        sizes = [tuple(int(v) for v in item.split(":")) for item in text.split(",")]
    except ValueError:
        sizes = []
    if not sizes or any(len(s) != 2 or min(s) < 1 for s in sizes):
        raise ValueError(f"--sizes must look like 5000:128,100000:512 (Gaussians:side), got {text!r}")
    return sizes


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.single_pass", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--backend", choices=("cuda", "cpu", "torch"), default="cuda" if torch.cuda.is_available() else "cpu"
    )
    p.add_argument(
        "--sizes", default=",".join(f"{n}:{r}" for n, r in DEFAULT_SIZES), help="Gaussians:side per expert"
    )
    p.add_argument("--experts", type=positive_int, default=3)
    p.add_argument("--rounds", type=positive_int, default=50)
    p.add_argument("--warmup", type=non_negative_int, default=5)
    p.add_argument(
        "--json",
        type=Path,
        action="append",
        help="write the result here; with --from-json, read it instead (repeat for later runs, whose "
        "speed-ups get a column each)",
    )
    p.add_argument("--from-json", action="store_true", help="only build the table from --json")
    p.add_argument("--readme", type=Path, help="rewrite this README's results:single-pass section")
    args = p.parse_args(argv)
    repeats = []
    if args.from_json:
        if not args.json or (missing := [str(path) for path in args.json if not path.is_file()]):
            p.error(
                f"--from-json needs existing --json files, missing: {missing if args.json else 'none given'}"
            )
        result, *repeats = [json.loads(path.read_text()) for path in args.json]
    else:
        if args.json and len(args.json) > 1:
            p.error("a new run writes one --json file")
        try:
            sizes = parse_sizes(args.sizes)
        except ValueError as exc:
            p.error(str(exc))
        cases = [
            measure(
                n,
                res,
                backend=args.backend,
                backward=backward,
                experts=args.experts,
                rounds=args.rounds,
                warmup=args.warmup,
            )
            for n, res in sizes
            for backward in (False, True)
        ]
        result = {
            "backend": args.backend,
            "experts": args.experts,
            "rounds": args.rounds,
            "warmup": args.warmup,
            "device": describe_device(torch.device("cuda" if args.backend == "cuda" else "cpu")),
            "date": datetime.now(UTC).strftime("%Y-%m-%d"),
            "torch": torch.__version__,
            "cases": cases,
        }
        if args.json:
            write_json_atomic(args.json[0], result)
    table = markdown(result, repeats)
    print(table)
    if args.readme:
        from bench.readme import update_readme

        update_readme(args.readme, "single-pass", table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
