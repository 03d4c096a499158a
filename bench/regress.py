"""Did a change make the benchmarks slower, hungrier or different? Two pytest-benchmark runs, case by case.

    tox -e bench                          # before the change (autosaved under .benchmarks/)
    tox -e bench                          # after it, in the same session on the same machine
    python -m bench.regress               # the two newest autosaved runs: exit 1 on a regression
    python -m bench.regress BASE.json NEW.json --time 0.10 --memory 0.05

pytest-benchmark compares times (``--benchmark-compare-fail``) but not the peak memory our suites
record in ``extra_info``, nor the results they record beside a timing (``mean_loss`` of the training
benchmark: a speed-up that changes results is not a speed-up). This compares all three for every case
both runs hold: the median time ratio, the render's peak memory (``bench.rasterizer.peak_mb``) and the
recorded results. Times of two runs are only comparable on one machine under the same load, so run both
in one session, nothing else running, with the same thread settings (``OMP_NUM_THREADS``: another
count may also change a loss in its last bits, which shows as "results differ"). The default allows
25 % on time: two runs of the same code on the 2-core CPU machine differed by up to 15 % on the
smallest render case (5 rounds each); run the suite twice before the change (an A/A comparison) to see
the noise of yours, and pass ``--time`` to match.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

from bench.rasterizer import peak_mb
from moegs.cli_types import non_negative_float

SAVED = Path(".benchmarks")  # pytest-benchmark's --benchmark-autosave folder, under the working directory
RESULT_KEYS = ("mean_loss",)  # extra_info values a benchmark computes, which a speed change must not move
MEMORY_SLACK_MB = 2.0  # RSS moves by a page table or two between processes: no verdict below this


@dataclass(frozen=True)
class Change:
    """One case present in both runs: ``time`` is new / base; ``memory_mb`` (base, new) peak MB, None when a
    run did not record it."""

    name: str
    time: float
    memory_mb: tuple[float, float] | None
    checked: tuple[str, ...]  # the RESULT_KEYS the base run recorded
    results: tuple[str, ...]  # those whose values differ

    @property
    def memory(self) -> float | None:
        """New / base peak memory, the base taken as at least ``MEMORY_SLACK_MB``."""
        return None if self.memory_mb is None else self.memory_mb[1] / max(self.memory_mb[0], MEMORY_SLACK_MB)


def read_run(path: Path) -> dict[str, dict]:
    """``{fullname: benchmark}`` of a pytest-benchmark JSON; ``ValueError`` naming the file otherwise."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        run = {b["fullname"]: b for b in data["benchmarks"]}
        bad = [name for name, b in run.items() if not 0 < b["stats"]["median"] < math.inf]
    except FileNotFoundError:
        raise ValueError(f"{path}: no such benchmark JSON") from None
    except (json.JSONDecodeError, KeyError, TypeError) as err:
        raise ValueError(
            f"{path}: not a pytest-benchmark JSON (needs benchmarks[].fullname and .stats.median): {err!r}"
        ) from err
    if bad:
        raise ValueError(f"{path}: median time not a positive number for {bad}")
    return run


def newest_runs(folder: Path = SAVED, count: int = 2) -> list[Path]:
    """The ``count`` newest autosaved runs (``NNNN_*.json``, oldest first) of the machine folder under
    ``folder`` that holds the newest one: pytest-benchmark numbers each machine's runs on its own."""
    saved = list(folder.glob("*/[0-9][0-9][0-9][0-9]_*.json"))
    if not saved:
        raise ValueError(f"{folder}: 0 autosaved run(s), need {count} (run `tox -e bench` twice)")
    machine = max(saved, key=lambda p: p.stat().st_mtime).parent
    runs = sorted(p for p in saved if p.parent == machine)  # by the run number the names start with
    if len(runs) < count:
        raise ValueError(f"{machine}: {len(runs)} autosaved run(s), need {count} (run `tox -e bench` twice)")
    return runs[-count:]


def compare(base: dict[str, dict], new: dict[str, dict]) -> list[Change]:
    """One ``Change`` per case both runs hold, in the new run's order."""
    out = []
    for name, b in new.items():
        if name not in base:
            continue
        a_info, b_info = base[name].get("extra_info", {}), b.get("extra_info", {})
        memory = (peak_mb(a_info), peak_mb(b_info))
        checked = tuple(k for k in RESULT_KEYS if k in a_info)
        differ = tuple(k for k in checked if a_info[k] != b_info.get(k))
        time = b["stats"]["median"] / base[name]["stats"]["median"]
        out.append(Change(name, time, None if None in memory else memory, checked, differ))
    return out


def regressions(changes: list[Change], time: float, memory: float) -> list[str]:
    """Why each regressed case fails: slower than ``1 + time``, more peak memory than ``1 + memory`` (and
    ``MEMORY_SLACK_MB``), or other results."""
    out = []
    for c in changes:
        if c.time > 1 + time:
            out.append(f"{c.name}: median time x{c.time:.2f} (limit x{1 + time:.2f})")
        if (
            c.memory is not None
            and c.memory > 1 + memory
            and c.memory_mb[1] - c.memory_mb[0] > MEMORY_SLACK_MB
        ):
            base, now = c.memory_mb
            out.append(
                f"{c.name}: peak memory {base:.0f} -> {now:.0f} MB (x{c.memory:.2f}, limit x{1 + memory:.2f})"
            )
        if c.results:
            out.append(f"{c.name}: results differ ({', '.join(c.results)})")
    return out


def markdown(changes: list[Change], base: Path, new: Path, only: tuple[list[str], list[str]]) -> str:
    """The comparison table, and the cases only one run holds."""
    lines = [
        f"Benchmarks: `{new}` against `{base}` (ratios new / base; > 1 is slower or larger)",
        "",
        "| case | median time | peak memory | results |",
        "|---|---|---|---|",
    ]
    for c in changes:
        memory = "–" if c.memory_mb is None else f"{c.memory_mb[0]:.0f} -> {c.memory_mb[1]:.0f} MB"
        if c.memory_mb is not None and c.memory_mb[0] >= MEMORY_SLACK_MB:  # a ratio of a few MB says nothing
            memory += f" (x{c.memory:.2f})"
        results = "differ: " + ", ".join(c.results) if c.results else "same" if c.checked else "–"
        lines.append(f"| {c.name.split('::')[-1]} | x{c.time:.2f} | {memory} | {results} |")
    for label, names in zip(("only in the base run", "only in the new run"), only, strict=True):
        if names:
            lines += ["", f"{label}: " + ", ".join(n.split("::")[-1] for n in names)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.regress", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "runs", nargs="*", type=Path, help="BASE.json NEW.json (default: the two newest autosaved)"
    )
    p.add_argument(
        "--time", type=non_negative_float, default=0.25, help="allowed median slow-down (default 0.25 = 25%%)"
    )
    p.add_argument(
        "--memory", type=non_negative_float, default=0.10, help="allowed peak-memory growth (default 0.10)"
    )
    args = p.parse_args(argv)
    if len(args.runs) not in (0, 2):
        p.error(f"give two runs (BASE.json NEW.json) or none, got {len(args.runs)}")
    try:
        base_path, new_path = args.runs or newest_runs()
        base, new = read_run(base_path), read_run(new_path)
    except ValueError as err:
        print(f"bench.regress: {err}", file=sys.stderr)
        return 2
    changes = compare(base, new)
    if not changes:
        print(f"bench.regress: {base_path} and {new_path} have no case in common", file=sys.stderr)
        return 2
    only = ([n for n in base if n not in new], [n for n in new if n not in base])
    print(markdown(changes, base_path, new_path, only))
    failed = regressions(changes, args.time, args.memory)
    for line in failed:
        print(f"REGRESSION {line}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
