"""What the run says about motion, routing and noise, read back from result JSONs (no torch).

* ``expert_rows``: every expert cell's PSNR / SSIM / LPIPS on the full image, the dynamic region and the
  static region, its PSNR per motion regime (stand-ins), and how much of the dynamic region's change over
  time it reproduces (temporal R²; one row per expert, scene and dataset recipe; seed 0, full training
  budget);
* ``routing_rows``: every MoE-GS cell's routing signal (``moegs.moe.winner_coherence`` of the winner map,
  and the share of dynamic / static pixels each expert wins);
* ``pruning_rows``: every pruned MoE-GS cell's share of Gaussians removed (each seed), beside the paper's
  memory reduction for that row (against its table's unpruned row, ``Spec.unpruned``);
* ``seed_noise``: the seed-to-seed spread (max - min over seeds) per scene and row, of the stability runs
  and of real-scene tables trained with several seeds; ``noise_for`` the spread a table's claims are
  judged against (its scenes' own, or the stand-ins' where a scene has none). Claims whose margin is
  inside it are "within noise";
* ``compute_rows``: what the run's cells cost, as each result recorded it when it was computed (training
  of every build, once however many cells share it, and every evaluation).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bench.cells._eval import REGIME_PREFIX
from bench.keys import digest
from bench.plan import Plan, make_plan
from bench.presets import get_preset
from bench.results import ResultError, read_result
from bench.scenes import load_kwargs
from bench.spec import METRICS
from bench.store import Workspace
from moegs.io import read_json

REGION_KEYS = {"full": "", "dynamic": "_dynamic", "static": "_static"}


def _ok_results(plan: Plan, workspace: Workspace, kind: str | None, once: bool = True):
    """``(spec plan, slot, result)`` of every finished ``kind`` evaluation (None: any), each task once
    (``once=False``: in every slot that uses it)."""
    seen: set[str] = set()
    for sp in plan.specs:
        for slot in sp.slots:
            task = slot.task
            if task is None or (kind is not None and task.kind != kind) or (once and task.key in seen):
                continue
            seen.add(task.key)
            path = workspace.result_path(task)
            try:
                result = read_result(path) if path.is_file() else None
            except ResultError:
                continue
            if result is not None and result.get("status") == "ok":
                yield sp, slot, result


def _regions(metrics: dict[str, Any], name: str) -> dict[str, float | None]:
    return {region: metrics.get(f"{name}{suffix}") for region, suffix in REGION_KEYS.items()}


def regime_psnrs(metrics: dict[str, Any]) -> dict[str, float]:
    """``{motion regime: PSNR}`` of a cell's metrics (its ``psnr_regime_*`` keys; empty on real scenes)."""
    return {k.removeprefix(REGIME_PREFIX): v for k, v in metrics.items() if k.startswith(REGIME_PREFIX)}


def per_camera_psnr(per_view: list[dict[str, Any]]) -> dict[str, float]:
    """``{camera id: mean PSNR of its views}`` (each view's ``camera``, recorded by the evaluation);
    empty with fewer than two cameras (one held-out camera, or a monocular scene)."""
    by_camera: dict[str, list[float]] = {}
    for view in per_view:
        if view.get("psnr") is not None:
            by_camera.setdefault(str(view["camera"]), []).append(view["psnr"])
    if len(by_camera) < 2:
        return {}
    return {camera: sum(v) / len(v) for camera, v in sorted(by_camera.items(), key=lambda kv: int(kv[0]))}


def expert_rows(plan: Plan, workspace: Workspace) -> list[dict[str, Any]]:
    """``[{"scene", "dataset", "expert", "preset", "psnr": {"full", "dynamic", "static"}, "ssim": ...,
    "lpips": ..., "psnr_regimes": {category: PSNR}, "motion_r2", "psnr_cameras": {camera: PSNR}}]`` of the
    seed-0, full-budget expert cells (``psnr_regimes``: a stand-in's motion regimes, empty on real scenes;
    ``motion_r2``: the temporal R² of the dynamic region, ``moegs.metrics.motion``; None where no test
    camera is seen at several times with masks; ``psnr_cameras``: ``per_camera_psnr`` on real scenes)."""
    rows: dict[tuple[str, str, str], dict[str, Any]] = {}
    for _sp, slot, result in _ok_results(plan, workspace, "expert"):
        task = slot.task
        if task.seed != 0 or "budget" in task.params:
            continue
        key = (task.scene, task.params.get("dataset", ""), task.params["expert"])
        m = result["metrics"]
        rows.setdefault(
            key,
            {
                "scene": task.scene,
                "dataset": task.params.get("dataset"),
                "expert": task.params["expert"],
                "preset": task.preset,
                **{name: _regions(m, name) for name in ("psnr", "ssim", "lpips")},
                "psnr_regimes": regime_psnrs(m),
                "motion_r2": m.get("motion_r2"),
                "psnr_cameras": per_camera_psnr(result.get("per_view", []))
                if result.get("scene", {}).get("real")
                else {},
            },
        )
    return sorted(rows.values(), key=lambda r: (r["scene"], r["dataset"] or "", r["expert"]))


def routing_rows(plan: Plan, workspace: Workspace) -> list[dict[str, Any]]:
    """``[{"table", "scene", "experts", "router", "coherence", "dynamic_share", "static_share"}]`` of the
    seed-0 MoE-GS cells that report a routing signal."""
    rows = []
    for sp, slot, result in _ok_results(plan, workspace, "moe"):
        task = slot.task
        routing = result.get("details", {}).get("routing")
        if task.seed != 0 or not routing:
            continue
        rows.append(
            {
                "table": sp.spec.id,
                "row": slot.row,
                "scene": task.scene,
                "experts": list(task.params["experts"]),
                "router": task.params.get("router", "vapr"),
                **routing,
            }
        )
    return rows


def pruning_rows(plan: Plan, workspace: Workspace) -> list[dict[str, Any]]:
    """``[{"table", "row", "scene", "seed", "when", "before", "after", "removed", "paper_memory_removed"}]``
    of the MoE-GS cells that pruned; ``paper_memory_removed`` is ``1 - row / unpruned row`` of the paper
    table's Memory column (``Spec.unpruned``; None where either is missing)."""
    from bench.paper import list_paper_tables, load_paper_table

    rows = []
    for sp, slot, result in _ok_results(plan, workspace, "moe", once=False):
        pruning = result.get("details", {}).get("pruning")
        if not pruning:
            continue
        memory = {}
        if sp.spec.id in list_paper_tables():
            memory = {
                v["row"]: v["value"]
                for v in load_paper_table(sp.spec.id).values
                if v["metric"] == "Memory" and isinstance(v["value"], int | float)
            }
        reference = memory.get(sp.spec.unpruned)
        paper = 1.0 - memory[slot.row] / reference if slot.row in memory and reference else None
        rows.append(
            {
                "table": sp.spec.id,
                "row": slot.row,
                "scene": slot.task.scene,
                "seed": slot.task.seed,
                "when": pruning.get("when", "after training"),
                "before": sum(pruning["before"]),
                "after": sum(pruning["after"]),
                "removed": pruning["removed_fraction"],
                "paper_memory_removed": paper,
            }
        )
    return rows


def seed_noise(plan: Plan, workspace: Workspace) -> dict[str, Any]:
    """Seed-to-seed spreads (max - min over seeds) of every row that finished two or more seeds on a scene
    (stability runs, and the tables of scenes without one at presets with ``scene_seeds``), per metric name of
    ``bench.spec.METRICS``::

        {"preset": plan's preset,
         "scenes": {scene: {"real", "preset", "seeds", "source": [spec ids], "rows": {row: {name: dB}},
                            "metrics": {name: dB, the largest over its rows}}},
         "metrics": {name: dB}, "source": [spec ids]}

    A scene's ``metrics`` is the largest spread of the rows of its stability run (a spec on the ``seeds``
    axis: Table IX) where it has one, else of every row: a table that trains more seeds of a stability
    scene (``BenchPreset.table_seeds``) judges its rows against their own and paired spreads, and an
    unstable row of it (a pruning that fails at one seed) does not become every other table's noise.
    ``metrics`` (with its ``source``) at the top is the largest spread measured on a stand-in: the noise of
    a scene without repeated trainings of its own (``noise_for``). A row's spread (``rows``), and a pair's
    (``pairs``), is its stability run's where that run measures it, else the largest over the tables that
    trained it: one label can name two models (Table VII's pruned "MoE-GS (N=3)", Table IX's unpruned one),
    and the stability run's is the one other tables print. Empty when nothing has two finished seeds."""
    stability = {sp.spec.id for sp in plan.specs if sp.spec.axis == "seeds"}
    widest: dict[tuple[str, bool], dict[str, float]] = {}  # (scene, from its stability run) -> spreads
    per_seed: dict[tuple[str, str, str, str | None], dict[int, tuple[str, dict[str, Any]]]] = {}
    real: dict[str, bool] = {}
    scenes: dict[str, dict[str, Any]] = {}
    cells: dict[str, set[str]] = {}  # per scene: the evaluation keys its spreads come from
    row_spreads: dict[tuple[str, str, bool], dict[str, float]] = {}  # (scene, row, from its stability run)
    for sp, slot, result in _ok_results(plan, workspace, None, once=False):
        real[slot.scene.name] = slot.scene.real
        key = (slot.scene.name, sp.spec.id, slot.row, slot.budget_column)
        per_seed.setdefault(key, {})[slot.seed] = (slot.task.key, result["metrics"])
    for (scene, spec_id, row, _column), seeds in per_seed.items():
        if len(seeds) < 2:
            continue
        cells.setdefault(scene, set()).update(task_key for task_key, _ in seeds.values())
        results = [metrics for _, metrics in seeds.values()]
        entry = scenes.setdefault(
            scene,
            {
                "real": real[scene],
                "preset": plan.preset.name,
                "seeds": 0,
                "source": [],
                "rows": {},
                "metrics": {},
            },
        )
        entry["seeds"] = max(entry["seeds"], len(results))
        if spec_id not in entry["source"]:
            entry["source"].append(spec_id)
        spreads = row_spreads.setdefault((scene, row, spec_id in stability), {})
        largest = widest.setdefault((scene, spec_id in stability), {})
        for name, m in METRICS.items():
            values = [r.get(m.key) for r in results]
            if any(v is None for v in values):
                continue
            spread = max(values) - min(values)
            spreads[name] = max(spreads.get(name, 0.0), spread)
            largest[name] = max(largest.get(name, 0.0), spread)
    for scene, entry in scenes.items():
        stable = widest.get((scene, True))
        entry["metrics"] = stable if stable is not None else widest.get((scene, False), {})
        entry["cells"] = digest(sorted(cells[scene]))
        measured = {(row, stable): v for (name, row, stable), v in row_spreads.items() if name == scene}
        entry["rows"] = _prefer_stable(measured)
        entry["pairs"] = _paired_spreads(per_seed, scene, stability)
    return {"preset": plan.preset.name, "scenes": scenes, **_stand_in_spread(scenes)}


def _prefer_stable(measured: dict[tuple[str, bool], Any]) -> dict[str, Any]:
    """``{label: value}`` from ``{(label, from the stability run): value}``: the stability run's where it
    has one, in the order the labels were first measured."""
    out: dict[str, Any] = {}
    for label, _ in measured:
        if label not in out:
            out[label] = measured[(label, True)] if (label, True) in measured else measured[(label, False)]
    return out


def _paired_spreads(
    per_seed: dict[tuple[str, str, str, str | None], dict[int, tuple[str, dict[str, Any]]]],
    scene: str,
    stability: set[str],
) -> list[dict[str, Any]]:
    """``[{"rows": [a, b], "seeds": n, "metrics": {name: spread}}]``: for two rows of one table and column
    on ``scene`` trained with the same two or more seeds, the spread (max - min over those seeds) of the
    per-seed difference a - b: the noise of the difference a claim compares, which shared experts or seeds
    make smaller than either row's own spread. A pair the ``stability`` run measures is that run's; another
    measured in several tables keeps its largest."""
    groups: dict[tuple[str, str | None], dict[str, dict[int, dict[str, Any]]]] = {}
    for (name, spec_id, row, column), seeds in per_seed.items():
        if name == scene:
            groups.setdefault((spec_id, column), {})[row] = {s: m for s, (_, m) in seeds.items()}
    measured: dict[tuple[tuple[str, str], bool], dict[str, Any]] = {}
    for (spec_id, _column), rows in groups.items():
        names = sorted(rows)
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                common = sorted(set(rows[a]) & set(rows[b]))
                if len(common) < 2:
                    continue
                entry = measured.setdefault(
                    ((a, b), spec_id in stability), {"rows": [a, b], "seeds": len(common), "metrics": {}}
                )
                entry["seeds"] = max(entry["seeds"], len(common))
                for metric_name, m in METRICS.items():
                    diffs = [_difference(rows[a][s], rows[b][s], m.key) for s in common]
                    if None not in diffs:
                        spread = max(diffs) - min(diffs)
                        entry["metrics"][metric_name] = max(entry["metrics"].get(metric_name, 0.0), spread)
    pairs = _prefer_stable(measured)
    return [pairs[k] for k in sorted(pairs)]


def _difference(x: dict[str, Any], y: dict[str, Any], key: str) -> float | None:
    a, b = x.get(key), y.get(key)
    return None if a is None or b is None else a - b


def _stand_in_spread(scenes: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """``{"metrics": {name: the largest spread over the stand-ins}, "source": their spec ids}``."""
    fallback: dict[str, float] = {}
    sources: list[str] = []
    for entry in scenes.values():
        if entry["real"]:
            continue
        sources += [s for s in entry["source"] if s not in sources]
        for name, spread in entry["metrics"].items():
            fallback[name] = max(fallback.get(name, 0.0), spread)
    return {"metrics": fallback, "source": sources}


NOISE_PROXY = "quick"
"""The preset whose repeated seeds stand in for another preset's noise on a scene it trains once."""


def run_noise(plan: Plan, workspace: Workspace, committed: Path | None = None) -> dict[str, Any]:
    """``seed_noise`` of ``plan``, pooled with and completed by the spreads recorded in ``committed`` (the
    ``NOISE_PROXY`` preset's ``summary.json``, e.g. the committed quick outputs).

    * Pooled: where ``committed`` recorded a scene's spread from the same cells (the same evaluation
      keys: code, configs and seeds, ``"cells"``) that this run measured it from, i.e. the same run on
      another machine, each metric is judged against the larger of the two (``_pool``). A range over
      three seeds bounds the noise only loosely: the same cells on two machines measured 0.78 and 0.26 dB
      on the N3V stand-in and judged 12 of 99 claims differently. Pooled spreads are passed on by the
      summary, so a warm re-run judges as the run it repeats; other cells (other code) never pool.
    * Completed: a scene with no spread of its own borrows the one the ``NOISE_PROXY`` preset measured
      on it with the same specs in the same workspace, or else the one in ``committed`` (for a run on a
      machine without the quick cells, and for a quick run of a few tables, whose scenes' spreads come
      from tables it did not run: Table IX's for the N3V stand-in), where that preset loads the scene as
      this one does (a stand-in of another size, ``quick32``'s or ``tiny``'s, is another scene under the
      same name). A borrowed entry keeps ``"preset"`` (and, from a summary, ``"committed"``: which file
      and commit), so the report says so. A longer run's noise is not
      measured by a shorter one's, but a claim decided by less than the quick run's spread is not
      decided."""
    noise = seed_noise(plan, workspace)
    recorded = dict(_committed_noise(committed))
    for name, entry in noise["scenes"].items():
        if (other := recorded.get(name)) is not None and other.get("cells") == entry["cells"]:
            _pool(entry, other)
    noise.update(_stand_in_spread(noise["scenes"]))
    proxy_preset = get_preset(NOISE_PROXY)
    wanted = {
        s.name
        for sp in plan.specs
        for s in sp.scenes
        if load_kwargs(s, plan.preset) == load_kwargs(s, proxy_preset)
    }
    proxy = {}
    if plan.preset.name != NOISE_PROXY:
        proxy = seed_noise(make_plan([sp.spec for sp in plan.specs], proxy_preset, plan.device), workspace)[
            "scenes"
        ]
    for name, entry in [*proxy.items(), *recorded.items()]:
        if name in wanted:
            noise["scenes"].setdefault(name, entry)
    return noise


def _pool(entry: dict[str, Any], other: dict[str, Any]) -> None:
    """Raise ``entry``'s spreads to ``other``'s (the same cells' spreads recorded by another run) where
    those are larger; ``entry`` then keeps its own as ``own_metrics`` and names the other run in
    ``pooled_with``."""
    larger = {name: v for name, v in other["metrics"].items() if v > entry["metrics"].get(name, 0.0)}
    theirs = {tuple(p["rows"]): p["metrics"] for p in other.get("pairs", [])}
    for pair in entry.get("pairs", []):
        for name, v in theirs.get(tuple(pair["rows"]), {}).items():
            pair["metrics"][name] = max(pair["metrics"].get(name, 0.0), v)
    if larger:
        entry["own_metrics"] = dict(entry["metrics"])
        entry["metrics"].update(larger)
        entry["pooled_with"] = other["committed"]


def _committed_noise(path: Path | None) -> list[tuple[str, dict[str, Any]]]:
    """``[(scene, entry), ...]``: the ``NOISE_PROXY`` run's scene spreads recorded in the summary at
    ``path`` (none when there is no such file), each marked with the file and its commit."""
    if path is None or not path.is_file():
        return []
    summary = read_json(path, "quick summary")
    commit = ((summary.get("header") or {}).get("git") or {}).get("commit") or "?"
    scenes = (summary.get("noise") or {}).get("scenes") or {}
    return [
        (name, {**entry, "committed": f"{path.name} at git {commit[:7]}"})
        for name, entry in scenes.items()
        if entry.get("preset") == NOISE_PROXY
    ]


def noise_for(noise: dict[str, Any], scene_names: list[str]) -> dict[str, float]:
    """The noise claims over ``scene_names`` are judged against, per metric name: for each metric the
    largest of each scene's own spread (``seed_noise``), or the stand-ins' where a scene has none."""
    fallback = noise.get("metrics") or {}
    out: dict[str, float] = {}
    for scene in scene_names:
        own = (noise.get("scenes") or {}).get(scene, {}).get("metrics") or {}
        for name in {*fallback, *own}:
            spread = own.get(name, fallback.get(name))
            if spread is not None:
                out[name] = max(out.get(name, 0.0), spread)
    return out


def row_noise_for(noise: dict[str, Any], scene_names: list[str]) -> dict[tuple[str, str], float]:
    """``{(row, metric): spread}``: the seed spreads rows measured themselves on ``scene_names`` (a row's
    largest over the scenes), for claims that compare those rows (``bench.claims.noise_of``)."""
    out: dict[tuple[str, str], float] = {}
    for scene in scene_names:
        for row, spreads in ((noise.get("scenes") or {}).get(scene, {}).get("rows") or {}).items():
            for name, spread in spreads.items():
                if spread is not None:
                    out[(row, name)] = max(out.get((row, name), 0.0), spread)
    return out


def pair_noise_for(noise: dict[str, Any], scene_names: list[str]) -> dict[tuple[str, str, str], float]:
    """``{(a, b, metric): spread}`` with ``a < b``: the spread of the per-seed difference of two rows
    (``_paired_spreads``), the largest over ``scene_names``; a comparison of the two is judged against it
    (``bench.claims.noise_of``)."""
    out: dict[tuple[str, str, str], float] = {}
    for scene in scene_names:
        for pair in (noise.get("scenes") or {}).get(scene, {}).get("pairs") or []:
            a, b = pair["rows"]
            for name, spread in pair["metrics"].items():
                out[(a, b, name)] = max(out.get((a, b, name), 0.0), spread)
    return out


def _build_label(artifact: dict[str, Any]) -> str:
    """What a build made, in a few words: ``stg``, ``vapr router: ex4dgs+stg``, ``MoDE: fourdgs+ed3dgs``."""
    params = artifact.get("params", {})
    kind = artifact.get("kind", "?")
    if kind == "expert":
        return params.get("expert", "?")
    if kind == "moe":
        return f"{params.get('router', 'vapr')} router: " + "+".join(params.get("experts", []))
    if kind == "mode":
        return "MoDE: " + "+".join(params.get("experts", []))
    if kind == "distill":
        return f"{params.get('student', '?')} from " + "+".join(params.get("teacher", []))
    return kind


def compute_rows(plan: Plan, workspace: Workspace) -> dict[str, Any]:
    """``{"builds": [{"kind", "what", "count", "minutes"}], "evaluations": [{"kind", "count", "minutes"}],
    "minutes"}``: the single-process wall-clock minutes the finished cells of ``plan`` recorded, builds
    grouped by kind and what they made (each build once, though many cells share it), largest first."""
    builds: dict[str, dict[str, Any]] = {}
    evals: dict[str, list[float]] = {}
    for _sp, slot, result in _ok_results(plan, workspace, None):
        evals.setdefault(slot.task.kind, []).append(result.get("timings", {}).get("eval_s", 0.0))
        for key, artifact in result.get("artifacts", {}).items():
            builds.setdefault(key, artifact)
    grouped: dict[tuple[str, str], list[float]] = {}
    for artifact in builds.values():
        group = (artifact.get("kind", "?"), _build_label(artifact))
        grouped.setdefault(group, []).append(artifact.get("build_seconds") or 0.0)
    build_rows = [
        {"kind": kind, "what": what, "count": len(v), "minutes": sum(v) / 60}
        for (kind, what), v in grouped.items()
    ]
    eval_rows = [{"kind": kind, "count": len(v), "minutes": sum(v) / 60} for kind, v in evals.items()]
    return {
        "builds": sorted(build_rows, key=lambda r: (-r["minutes"], r["kind"], r["what"])),
        "evaluations": sorted(eval_rows, key=lambda r: (-r["minutes"], r["kind"])),
        "minutes": sum(r["minutes"] for r in build_rows + eval_rows),
    }
