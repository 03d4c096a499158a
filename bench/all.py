"""Reproduce the paper's tables and figures: ``python -m bench.all [--tiny|--quick|--standard|--paper]
[--tables 3,17] [--jobs N]``.

Steps: plan the selected specs (rows x scenes x seeds), build the missing artefacts and evaluate the
missing cells (local process pool or Slurm via submitit; finished work is reused), then write
``tables/<id>.tex``, ``reports/figures/*.png``, ``reports/REPORT.{md,html}`` and
``reports/summary.json``.

A run of every spec writes those under ``--out``. A subset run (``--tables 3,17``) writes the same
files for its specs only under ``reports/subsets/<ids>/`` and leaves the full report and tables as
they are, so the committed outputs always come from one complete run.

``--preset standard`` runs only the tables whose scenes are all real (the stand-in tables stay at quick)
and writes ``tables/standard/`` and ``reports/standard/``, including paper | standard | quick tables
(``bench.sidebyside``); the quick report shows the same comparison once the standard run exists.

Datasets without real data under ``MOEGS_DATA`` run on synthetic stand-ins; the run says so in one line
at the start, and ``--require-real`` makes it an error instead.

``--tables`` accepts ``tab03``, ``3``, ``III``, ``repro-tab3`` (tox env names) and figure ids; it is
the one entry point of every table (``tox -e repro-tab3`` calls it; spec modules are data). The preset
is ``--preset NAME`` or one of its shorthands ``--tiny``, ``--quick``, ``--standard``, ``--paper`` (two
that name different presets are an error), else ``$MOEGS_PRESET``, else ``quick``.

Before any work the run prints its plan (builds and evaluations to compute, and those cached) and an
estimate of its time from the task times the workspace recorded (``bench.forecast``: the same tasks under
older code, else similar ones, else 'unknown').

``--device auto|cpu|cuda`` (``auto``: CUDA when torch sees a GPU) is part of every cell's key, so CPU and
GPU numbers never mix. On CUDA the local executor runs ``--jobs-per-gpu`` workers on each of ``--gpus``
GPUs (default: every visible one); on Slurm ``--slurm-gpus`` makes the tasks CUDA tasks. ``--dry-run``
prints that plan, then each table's builds with an estimate of H100-hours and CPU-hours
(``bench.estimate``), and runs nothing. ``--preset paper`` on the CPU (no CUDA, or ``--device cpu``) prints
the plan and its estimate and stops unless ``--yes`` is given.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from bench.presets import DEFAULT_PRESET, PRESET_ENV, PRESETS, SHORTHANDS, default_preset, get_preset
from bench.registry import get_spec, list_specs, parse_selection
from moegs.cli_types import non_negative_int, positive_float, positive_int


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m bench.all",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--tables",
        nargs="*",
        metavar="ID",
        help="tables/figures to run (default: all), e.g. 3,17 tab03 repro-tab3 fig_mdc",
    )
    p.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        default=None,
        help=f"scale preset (default: ${PRESET_ENV} or {DEFAULT_PRESET!r}; now {default_preset()!r})",
    )
    for name in SHORTHANDS:
        p.add_argument(
            f"--{name}", dest="shorthands", action="append_const", const=name, help=f"same as --preset {name}"
        )
    p.add_argument(
        "--yes",
        action="store_true",
        help="run --preset paper on the CPU (without it such a run prints its plan and estimate and stops)",
    )
    p.add_argument(
        "--executor",
        choices=["local", "slurm", "submitit-local"],
        default="local",
        help="local process pool (default), Slurm via submitit, or submitit's local executor",
    )
    p.add_argument(
        "--device",
        default="auto",
        help="auto (CUDA when torch sees a GPU), cpu, cuda or cuda:<index>; part of every cell's key",
    )
    p.add_argument(
        "--jobs",
        type=positive_int,
        default=None,
        help="parallel tasks for the local executor on the CPU (default: one per CPU core, 1 thread each)",
    )
    p.add_argument(
        "--gpus",
        type=non_negative_int,
        default=None,
        help="GPUs the local executor uses on CUDA (default: every visible GPU; 0 without CUDA)",
    )
    p.add_argument(
        "--jobs-per-gpu",
        type=positive_int,
        default=None,
        help="workers per GPU on CUDA (default 1); CPU threads per worker = cores / workers",
    )
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="plan only: print each table's builds and an estimate of H100-hours and CPU-hours, then exit",
    )
    p.add_argument(
        "--seeds",
        type=positive_int,
        default=None,
        metavar="N",
        help="train N seeds on every scene of the selected tables (figures and stability runs keep theirs): "
        "they print N-seed means, and rows trained with the same seeds are judged against the spread of "
        "their difference; seeds a stability run trained are reused. The report names the claims that "
        "more seeds would decide",
    )
    p.add_argument("--timeout", type=positive_float, default=None, help="seconds per task (local executor)")
    p.add_argument(
        "--workspace",
        type=Path,
        default=None,
        help="results, checkpoints and logs (default: $MOEGS_BENCH_DIR or runs/bench)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path.cwd(),
        help="where tables/ and reports/ go (default: the working directory, i.e. the repository root)",
    )
    p.add_argument("--no-run", action="store_true", help="only rebuild tables, plots and report from results")
    p.add_argument(
        "--candidate",
        action="append",
        metavar="EXPERT",
        help="add an expert as a third-expert candidate to Table X: a registered name (a plugin's entry "
        "point) or package.module:Class",
    )
    p.add_argument(
        "--require-real",
        action="store_true",
        help="fail (before any work) when a selected table would run on a synthetic stand-in",
    )
    p.add_argument("--list", action="store_true", help="list the specs and exit (no torch import)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--slurm-partition", default=None)
    p.add_argument("--slurm-time", type=positive_int, default=240, help="minutes per task on Slurm")
    p.add_argument("--slurm-gpus", type=non_negative_int, default=None, help="GPUs per task on Slurm")
    p.add_argument("--slurm-cpus", type=positive_int, default=None, help="CPUs per task on Slurm")
    p.add_argument(
        "--slurm-pack",
        type=positive_int,
        default=1,
        help="ready tasks run one after another in one Slurm job (default 1; --slurm-time is per task)",
    )
    return p


def choose_preset(args: argparse.Namespace) -> str:
    """The preset the command line names (``--preset`` or a shorthand), else ``$MOEGS_PRESET``, else
    ``quick``; ``ValueError`` (one line) when flags name different presets or the variable an unknown one."""
    named = [(f"--{n}", n) for n in args.shorthands or []]
    if args.preset:
        named.append((f"--preset {args.preset}", args.preset))
    if len({name for _, name in named}) > 1:
        flags = " and ".join(dict.fromkeys(flag for flag, _ in named))
        raise ValueError(f"{flags} name different presets; give one")
    if named:
        return named[0][1]
    name = default_preset()
    if name not in PRESETS:
        raise ValueError(f"${PRESET_ENV}={name}: unknown bench preset; valid: {', '.join(PRESETS)}")
    return name


def list_table() -> str:
    rows = []
    for sid in list_specs():
        spec = get_spec(sid)
        rows.append(
            f"{sid:18s} {spec.dataset or '-':12s} {spec.axis:8s} {len(spec.rows):2d} rows  {spec.title}"
        )
    return "\n".join(rows)


def choose_device(args: argparse.Namespace) -> tuple[str, list[int]]:
    """``(device kind of the tasks, GPUs of the local executor)`` the command line asks for; ``ValueError``
    (one line) for a device this machine lacks or options that contradict it. Slurm runs take the kind
    from ``--slurm-gpus``; ``--no-run`` and ``--dry-run`` compute nothing, so need no GPU here."""
    name = args.device.strip().lower()
    if args.executor != "local":
        if args.gpus is not None or args.jobs_per_gpu is not None:
            raise ValueError(
                "--gpus and --jobs-per-gpu are for the local executor; on Slurm use --slurm-gpus"
            )
        if name == "cpu" and args.slurm_gpus:
            raise ValueError(f"--slurm-gpus {args.slurm_gpus} with --device cpu: a GPU nothing would use")
        if name.startswith("cuda") and not args.slurm_gpus:
            raise ValueError(f"--device {args.device} on Slurm needs --slurm-gpus N (GPUs per job)")
        return ("cuda" if args.slurm_gpus else "cpu"), []
    if name == "cpu":
        if args.gpus:
            raise ValueError(f"--gpus {args.gpus} with --device cpu: use --device cuda or auto for GPUs")
        if args.jobs_per_gpu is not None:
            raise ValueError("--jobs-per-gpu with --device cpu: use --jobs for CPU workers")
        return "cpu", []
    if args.no_run or args.dry_run:
        kind, _, index = name.partition(":")
        if kind == "cuda" and (not index or index.isdigit()):
            return "cuda", []
    import torch

    from moegs.device import resolve_device

    device = resolve_device(name)
    count = torch.cuda.device_count() if device.type == "cuda" else 0
    if args.gpus and args.gpus > count:
        have = (
            f"has {count} GPU(s) (CUDA_VISIBLE_DEVICES may hide others)" if count else "has no GPU torch sees"
        )
        raise ValueError(f"--gpus {args.gpus}: this machine {have}")
    if device.type == "cpu":
        if args.jobs_per_gpu is not None:
            raise ValueError("--jobs-per-gpu: this machine has no GPU torch sees; use --jobs for CPU workers")
        return "cpu", []
    if args.jobs is not None:
        raise ValueError(f"--jobs with --device {args.device}: on GPUs use --gpus and --jobs-per-gpu")
    if args.gpus == 0:
        raise ValueError(f"--gpus 0 with --device {args.device}: use --device cpu for a CPU run")
    if ":" in name:
        if args.gpus not in (None, 1):
            raise ValueError(f"--gpus {args.gpus} with --device {args.device}: that names one GPU")
        return "cuda", [device.index]
    return "cuda", list(range(args.gpus or count))


def workers(args: argparse.Namespace, kind: str, gpus: list[int]) -> int | None:
    """Tasks the local executor runs at once (None on Slurm, where the cluster decides)."""
    if args.executor != "local":
        return None
    if kind == "cuda":
        return len(gpus) * (args.jobs_per_gpu or 1) or None
    return args.jobs or os.cpu_count() or 1


def device_line(args: argparse.Namespace, kind: str, gpus: list[int]) -> str:
    """How outputs name the device of this run: ``cpu``, ``cuda (2 x NVIDIA H100 80GB HBM3)``."""
    if kind == "cpu":
        return "cpu"
    if args.executor != "local":
        return f"cuda ({args.slurm_gpus} GPU(s) per Slurm job)"
    if not gpus:
        return "cuda"
    import torch

    from moegs.device import gpu_model

    return f"cuda ({len(gpus)} x {gpu_model(torch.device('cuda', gpus[0]))})"


def _executor(args: argparse.Namespace, gpus: list[int] | None = None):
    from bench.executors import make_executor

    params = {"timeout_min": args.slurm_time * args.slurm_pack}
    if args.slurm_partition:
        params["slurm_partition"] = args.slurm_partition
    if args.slurm_gpus is not None:
        params["gpus_per_node"] = args.slurm_gpus
    if args.slurm_cpus is not None:
        params["cpus_per_task"] = args.slurm_cpus
    return make_executor(
        args.executor,
        jobs=args.jobs or os.cpu_count() or 1,
        timeout=args.timeout,
        parameters=params,
        threads=args.slurm_cpus,
        gpus=gpus or [],
        jobs_per_gpu=args.jobs_per_gpu or 1,
        pack=args.slurm_pack,
    )


def output_dirs(out: Path, preset, selected: list[str], complete: list[str]) -> tuple[Path, Path]:
    """``(tables, reports)`` folders of a run: ``out/tables`` and ``out/reports`` for a complete run of
    the default layout; a preset with ``separate_outputs`` (``standard``, ``quick32``) keeps its own
    ``<preset>/`` subfolders; a subset of ``complete`` goes under ``reports/subsets/[<preset>-]<ids>/``,
    leaving the full outputs."""
    if set(selected) != set(complete):
        own = f"{preset.name}-" if preset.separate_outputs else ""
        base = out / "reports" / "subsets" / (own + "-".join(selected))
        return base / "tables", base / "reports"
    if preset.separate_outputs:
        return out / "tables" / preset.name, out / "reports" / preset.name
    return out / "tables", out / "reports"


def write_outputs(
    plan,
    workspace,
    selected: list[str],
    tables_dir: Path,
    reports_dir: Path,
    run: dict | None = None,
    quick_summary: Path | None = None,
    device: str | None = None,
) -> dict:
    """Tables and plots for ``selected``, the report for every spec of ``plan``; a ``real_only`` preset
    also writes its paper | standard | quick tables (``bench.sidebyside``). ``quick_summary``: the quick
    outputs' ``summary.json``, whose seed spreads a quick run pools with its own and a run at another
    preset borrows for the scenes whose quick cells are not in ``workspace`` (``bench.signals.run_noise``).
    ``device``: how the headers name the run's device (default: the plan's device kind)."""
    from bench.latex import write_index, write_table
    from bench.plots import plot_spec
    from bench.report import spec_report, write_report
    from bench.runlog import runs_of
    from bench.sidebyside import compare
    from bench.sidebyside import write_latex as write_comparison
    from bench.signals import (
        compute_rows,
        expert_rows,
        noise_for,
        pair_noise_for,
        pruning_rows,
        routing_rows,
        row_noise_for,
        run_noise,
    )
    from bench.values import SpecValues

    reports, written, comparisons = [], [], []
    device = device or plan.device
    header = f"preset {plan.preset.name}, device {device}, generated {time.strftime('%Y-%m-%d %H:%M')}"
    noise = run_noise(plan, workspace, quick_summary)
    for sp in plan.specs:
        names = [s.name for s in sp.scenes]
        values = SpecValues(
            sp, workspace, noise_for(noise, names), row_noise_for(noise, names), pair_noise_for(noise, names)
        )
        latex, figures = None, []
        if sp.spec.id in selected:
            if not sp.spec.figure:
                latex = write_table(values, plan.preset, tables_dir, header)
                written.append(latex)
            figures = plot_spec(values, reports_dir / "figures")
        else:  # keep figures of earlier runs in the report
            figures = sorted((reports_dir / "figures").glob(f"{sp.spec.id}_*.png")) + sorted(
                (reports_dir / "figures").glob(f"{sp.spec.id}.png")
            )
            old = tables_dir / f"{sp.spec.id}.tex"
            latex = old if old.is_file() else None
        reports.append(spec_report(values, plan.preset, latex, figures))
        comparison = compare(sp.spec, workspace, device=plan.device)
        if comparison is not None and comparison.has_values:
            comparisons.append(comparison)
            if plan.preset.real_only and sp.spec.id in selected:
                written.append(write_comparison(comparison, tables_dir, header))
    all_tex = sorted(p for p in tables_dir.glob("*.tex") if p.name != "all.tex")
    if all_tex:
        write_index(all_tex, tables_dir)
    signals = {
        "noise": noise,
        "experts": expert_rows(plan, workspace),
        "routing": routing_rows(plan, workspace),
        "pruning": pruning_rows(plan, workspace),
        "presets": comparisons,
        "compute": compute_rows(plan, workspace),
    }
    identity = plan.identity()
    history = runs_of(workspace.root, identity["keys_digest"])
    paths = write_report(reports, plan.preset, reports_dir, run, signals, identity, history, device)
    return {"reports": reports, "paths": paths, "tables": written}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.list:
        print(list_table())
        return 0
    try:
        selected = parse_selection(args.tables)
    except KeyError as err:
        print(f"error: {err.args[0]}", file=sys.stderr)
        return 2
    try:
        preset = get_preset(choose_preset(args))
        device, gpus = choose_device(args)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2

    from dataclasses import fields, replace

    if args.seeds is not None:
        preset = replace(preset, table_seeds={**preset.table_seeds, **dict.fromkeys(selected, args.seeds)})

    from bench.plan import make_plan
    from bench.runlog import read_runs, record_run
    from bench.store import Workspace

    workspace = Workspace(args.workspace)
    try:
        for flag, folder in (("--workspace", workspace.root), ("--out", args.out.resolve())):
            existing = next(p for p in (folder, *folder.parents) if p.exists())
            if not existing.is_dir():
                raise ValueError(
                    f"{flag} {folder}: {existing} is a file; expected a folder (created when missing)"
                )
        read_runs(workspace.root)  # a damaged record stops the command now, not after the cells
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    specs = [get_spec(s) for s in list_specs()]
    if args.candidate:
        specs = with_candidates(specs, selected, args.candidate)
        if specs is None:
            return 2
    plan = make_plan(specs, preset, device)
    run_plan = replace(plan, specs=[sp for sp in plan.specs if sp.spec.id in selected])
    complete = list_specs()
    if preset.real_only:
        complete = [sp.spec.id for sp in plan.specs if sp.scenes and not sp.uses_stand_in]
        skipped = [s for s in selected if s not in complete]
        selected = [s for s in selected if s in complete]
        if skipped:
            print(
                f"[bench] preset {preset.name} runs real scenes only; stand-in tables stay at quick: "
                f"{', '.join(skipped)}",
                file=sys.stderr,
            )
        if not selected:
            print(
                f"[bench] error: no selected table runs on real data at preset {preset.name}", file=sys.stderr
            )
            return 2
        plan = replace(plan, specs=[sp for sp in plan.specs if sp.spec.id in complete])
        run_plan = replace(plan, specs=[sp for sp in plan.specs if sp.spec.id in selected])
    stand_ins = data_line(run_plan)
    if stand_ins:
        print(f"[bench] {stand_ins}", file=sys.stderr)
        if args.require_real:
            print("[bench] error: --require-real and real data is missing (see above)", file=sys.stderr)
            return 2
    on = device_line(args, device, gpus)
    shown = ", ".join(selected) if len(selected) <= 6 else f"{', '.join(selected[:5])} ..."
    print(
        f"[bench] preset {preset.name}, device {on}; {len(selected)} spec(s): {shown}; "
        f"workspace {workspace.root}",
        file=sys.stderr,
    )
    if not args.no_run:
        from bench.forecast import forecast, plan_lines

        lines = plan_lines(
            forecast(run_plan, workspace), workers(args, device, gpus), workspace.root, preset.name, device
        )
        for line in lines:
            print(f"[bench] {line}", file=sys.stderr)
    if args.dry_run:
        from bench.estimate import render

        print(render(run_plan, device))
        return 0
    if preset.name == "paper" and device == "cpu" and not args.no_run and not args.yes:
        from bench.estimate import plan_estimates

        total = plan_estimates(run_plan)[1]
        cpu, gpu = (f"{h:.1f}" if h < 10 else f"{h:.0f}" for h in (total.cpu_hours, total.gpu_hours))
        print(
            f"error: --preset paper on the CPU: about {cpu} CPU-hours "
            f"({gpu} H100-hours on a GPU, bench/estimate.py) for the selected tables "
            "(--dry-run lists them); pass --yes to run it on the CPU anyway",
            file=sys.stderr,
        )
        return 2
    subset = set(selected) != set(complete)
    tables_dir, reports_dir = output_dirs(args.out, preset, selected, complete)
    run = None
    if not args.no_run:
        executor = _executor(args, gpus)
        try:
            summary = execute_interruptibly(run_plan, workspace, executor, not args.no_progress)
        except KeyboardInterrupt:
            print(
                "[bench] interrupted: finished cells and training checkpoints are kept; run the same "
                "command again to resume",
                file=sys.stderr,
            )
            return 130
        run = {  # not asdict(summary): a failure's Task holds read-only mappings that cannot be copied
            **{f.name: getattr(summary, f.name) for f in fields(summary) if f.name != "failures"},
            "failures": [  # logs relative to the workspace: no machine's absolute paths in outputs
                {"task": o.task.slug, "log": os.path.relpath(o.log, workspace.root), "error": o.error}
                for o in summary.failures
            ],
        }
    quick_summary = output_dirs(args.out, get_preset("quick"), complete, complete)[1] / "summary.json"
    reported = run_plan if subset else plan
    if run is not None:  # before the outputs, so that this run's report lists it too
        jobs = executor.jobs if args.executor == "local" else None
        seconds = time.perf_counter() - start
        record_run(
            workspace.root, preset.name, reported.identity(), run, args.executor, jobs, seconds, device=on
        )
    outputs = write_outputs(reported, workspace, selected, tables_dir, reports_dir, run, quick_summary, on)
    elapsed = time.perf_counter() - start
    _print_summary(outputs["reports"], selected, outputs["paths"], elapsed, f"preset {preset.name}, {on}")
    if run and run["failures"]:
        print(
            f"[bench] {len(run['failures'])} task(s) failed; see the logs above and the report",
            file=sys.stderr,
        )
        return 1
    return 0


def with_candidates(specs: list, selected: list[str], names: list[str]) -> list | None:
    """``specs`` with every selected spec that takes candidate experts (``Spec.candidates``: Table X)
    extended by ``names`` (None, after saying why, when no selected spec takes them or a name is not a
    registered expert)."""
    from moegs.experts import get_spec as expert_spec

    takers = [s.id for s in specs if s.candidates is not None]
    if not set(takers) & set(selected):
        print(f"error: --candidate extends {', '.join(takers)}: select it with --tables", file=sys.stderr)
        return None
    try:
        names = [register_candidate(n) if ":" in n else n for n in names]
        for name in names:
            expert_spec(name)
    except (ImportError, ValueError) as err:
        print(f"error: --candidate: {err}", file=sys.stderr)
        return None
    return [s.candidates(s, tuple(names)) if s.id in selected and s.candidates else s for s in specs]


def register_candidate(target: str) -> str:
    """Register the expert class ``package.module:Class`` for this run and its workers (through
    ``$MOEGS_EXPERTS``) under the class's ``name``; returns that name."""
    import importlib

    from moegs.experts import EXPERTS_ENV, reload_plugins

    module, _, attr = target.partition(":")
    cls = getattr(importlib.import_module(module), attr, None)
    name = getattr(cls, "name", "")
    if not name:
        raise ValueError(f"{target} is not an expert class with a registry name (class attribute `name`)")
    entries = [e for e in os.environ.get(EXPERTS_ENV, "").split(",") if e]
    os.environ[EXPERTS_ENV] = ",".join([*entries, f"{name}={target}"])
    reload_plugins()
    return name


def execute_interruptibly(plan, workspace, executor, progress: bool):
    """``bench.runner.execute`` with SIGTERM handled like Ctrl-C (``KeyboardInterrupt``)."""
    import signal

    from bench.runner import execute

    def stop(_signum, _frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        return execute(plan, workspace, executor, progress=progress)
    finally:
        signal.signal(signal.SIGTERM, previous)


def data_root_text() -> str:
    from moegs.paths import data_root

    root = data_root()
    return f"MOEGS_DATA={root}" if root is not None else "no MOEGS_DATA (and no ../shared/data)"


def data_line(plan) -> str:
    """One line naming the datasets of ``plan`` that run on synthetic stand-ins ('' when none does)."""
    missing = sorted({f"{sp.spec.dataset} -> {s.name}" for sp in plan.specs for s in sp.scenes if not s.real})
    if not missing:
        return ""
    where = data_root_text()
    return f"no real data for {len(missing)} dataset(s) under {where}: stand-ins {', '.join(missing)}"


def _print_summary(reports, selected, paths, elapsed: float, what: str = "") -> None:
    from rich.console import Console
    from rich.table import Table

    from bench.report import claims_by_kind

    title = f"moegs bench ({what}, {elapsed:.0f} s)" if what else f"moegs bench ({elapsed:.0f} s)"
    table = Table(title=title, show_lines=False)
    for col in ("id", "status", "claims (ours)"):
        table.add_column(col, overflow="fold")
    for rep in reports:
        if rep.id in selected:
            table.add_row(rep.id, rep.status, claims_by_kind(rep.claims))
    console = Console(stderr=True)
    console.print(table)
    console.print(f"report: {paths['md']}  (html: {paths['html']})")


if __name__ == "__main__":
    sys.exit(main())
