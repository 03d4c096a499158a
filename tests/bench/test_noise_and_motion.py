"""Claims that know the seed noise, claims re-checked on the dynamic region, and the routing signal."""

from __future__ import annotations

import json

import pytest
import torch
from helpers.cells import staged_scenes, write_ok_result

from bench.claims import (
    AGAINST_PAPER,
    FAILED,
    HELD,
    NA,
    NOISE,
    NOT_JUDGED,
    WITH_PAPER,
    at_least,
    best,
    better,
    differs_across,
    evaluate,
    exceeds,
    monotone,
    order,
    seeds_to_decide,
    spread,
    within,
)
from bench.registry import get_spec, list_specs
from bench.report import claim_counts, claims_by_kind, verdict
from bench.spec import Claim
from moegs.moe import region_shares, winner_coherence


class View:
    """A values view over ``{(row, column, metric): value}`` with an optional noise level."""

    def __init__(self, values: dict, noise: dict | None = None) -> None:
        self.values, self.noise = values, noise or {}

    def get(self, row, column, metric):
        return self.values.get((row, column, metric))

    def columns(self, selector):
        return ["@mean"] if selector == "@mean" else list(selector)

    def metrics_of(self, column):
        return list(dict.fromkeys(m for _, c, m in self.values if c == column))


class Scenes(View):
    """A view whose ``@scenes`` are the columns s1 and s2."""

    def columns(self, selector):
        return ["s1", "s2"] if selector == "@scenes" else super().columns(selector)


def psnr(**rows) -> dict:
    return {(r, "@mean", "PSNR"): v for r, v in rows.items()}


@pytest.mark.parametrize(
    ("a", "b", "noise", "status"),
    [
        (28.5, 28.0, 0.0, HELD),  # no noise measured: the sign decides
        (28.5, 28.0, 0.3, HELD),  # 0.5 dB margin > 0.3 dB spread
        (28.2, 28.0, 0.3, NOISE),  # 0.2 dB margin inside the spread: decides nothing
        (27.9, 28.0, 0.3, NOISE),
        (27.5, 28.0, 0.3, FAILED),  # behind by more than the spread
    ],
)
def test_better_knows_the_noise(a, b, noise, status):
    assert better(View(psnr(A=a, B=b), {"PSNR": noise}), "A", "B").status == status


def test_lpips_direction_and_other_checks_with_noise():
    v = View({("A", "@mean", "LPIPS"): 0.10, ("B", "@mean", "LPIPS"): 0.11}, {"LPIPS": 0.02})
    assert better(v, "A", "B", metric="LPIPS").status == NOISE
    v = View(psnr(A=30.0, B=29.9, C=25.0), {"PSNR": 0.2})
    assert order(v, ["A", "B", "C"]).status == NOISE  # A > B within noise, B > C clearly
    assert order(View(psnr(A=30.0, B=31.0, C=25.0), {"PSNR": 0.2}), ["A", "B", "C"]).status == FAILED
    assert within(View(psnr(A=30.0, B=30.25), {"PSNR": 0.2}), "A", "B", tolerance=0.1).status == NOISE
    assert within(View(psnr(A=30.0, B=30.5), {"PSNR": 0.2}), "A", "B", tolerance=0.1).status == FAILED
    steps = View({("A", c, "PSNR"): x for c, x in (("1", 30.0), ("2", 30.1))}, {"PSNR": 0.2})
    assert monotone(steps, ["A"], ["1", "2"]).status == NOISE
    assert (
        exceeds(
            View({("A", "x", "PSNR"): 30.0, ("B", "y", "PSNR"): 29.9}, {"PSNR": 0.2}), "A", "x", ["B"], "y"
        ).status
        == NOISE
    )
    assert better(View({}), "A", "B").status == NA


def test_a_comparison_lost_beyond_the_noise_fails_the_claim_whatever_the_others_say():
    """One scene inside the spread does not excuse another lost beyond it."""
    scenes = {("A", "s1", "PSNR"): 28.1, ("B", "s1", "PSNR"): 28.0, ("A", "s2", "PSNR"): 27.0,
              ("B", "s2", "PSNR"): 28.0}  # fmt: skip
    assert better(View(scenes, {"PSNR": 0.3}), "A", "B", columns=["s1", "s2"]).status == FAILED
    # the same in a chain: A > B within noise, B > C lost by 1 dB
    assert order(View(psnr(A=30.1, B=30.0, C=31.0), {"PSNR": 0.3}), ["A", "B", "C"]).status == FAILED


@pytest.mark.parametrize(("strict", "status"), [(True, FAILED), (False, HELD)])
def test_a_tie_fails_a_strict_claim_and_holds_a_non_strict_one(strict, status):
    assert better(View(psnr(A=28.0, B=28.0)), "A", "B", strict=strict).status == status


def test_a_margin_moves_the_decision_boundary_and_the_noise_band_sits_around_it():
    """A strict claim needs a lead above ``margin``; a non-strict one forgives a lag up to it. The seed
    spread blurs the boundary, not zero: 0.1 dB from it is noise, 0.4 dB under it fails."""

    def lead(a: float, noise: float = 0.0) -> View:
        return View(psnr(A=a, B=28.0), {"PSNR": noise})

    assert better(lead(28.6), "A", "B", margin=0.5).status == HELD
    assert better(lead(28.4), "A", "B", margin=0.5).status == FAILED
    assert better(lead(27.6), "A", "B", strict=False, margin=0.5).status == HELD
    assert better(lead(27.4), "A", "B", strict=False, margin=0.5).status == FAILED
    assert better(lead(28.6, 0.2), "A", "B", margin=0.5).status == NOISE
    assert better(lead(28.1, 0.2), "A", "B", margin=0.5).status == FAILED


def test_ties_and_edges_of_the_other_checks():
    assert order(View(psnr(A=30.0, B=30.0)), ["A", "B"]).status == FAILED  # an order is strict by default
    assert best(View(psnr(A=30.0, B=29.0)), "A", ["A", "B"], strict=True).status == HELD  # not against itself
    assert at_least(View(psnr(A=0.1)), ["A"], 0.1, "PSNR", columns="@mean").status == HELD
    flat = View({("A", "1", "PSNR"): 30.0, ("A", "2", "PSNR"): 30.0})
    assert monotone(flat, ["A"], ["1", "2"]).status == HELD  # a tie is not a gain
    rising = View({("A", "1", "LPIPS"): 0.1, ("A", "2", "LPIPS"): 0.2})  # LPIPS rising: getting worse
    assert monotone(rising, ["A"], ["1", "2"], metric="LPIPS").status == HELD
    falling = View({("A", "1", "LPIPS"): 0.2, ("A", "2", "LPIPS"): 0.1})
    assert monotone(falling, ["A"], ["1", "2"], metric="LPIPS").status == FAILED


def test_a_scene_where_one_row_has_a_value_names_no_winner():
    """``differs_across`` needs a contest: a scene computed for B alone does not make B a winner."""
    one_sided = {("A", "s1", "PSNR"): 30.0, ("B", "s1", "PSNR"): 29.0, ("B", "s2", "PSNR"): 31.0}
    assert differs_across(Scenes(one_sided), ["A", "B"]).status == NA


def test_equal_values_do_not_exceed_or_make_a_row_more_stable():
    tie = View({("A", "Average", "PSNR"): 30.0, ("B", "Max", "PSNR"): 30.0})
    assert exceeds(tie, "A", "Average", ["B"], "Max").status == FAILED
    ranges = {("A", "Min", "PSNR"): 29.0, ("A", "Max", "PSNR"): 30.0, ("B", "Min", "PSNR"): 28.0,
              ("B", "Max", "PSNR"): 29.0}  # fmt: skip
    assert spread(View(ranges), "A", ["B"]).status == FAILED  # the same 1 dB range: not more stable
    ranges[("A", "Min", "PSNR")] = 29.5
    assert spread(View(ranges), "A", ["B"]).status == HELD


def test_the_winner_of_a_lower_is_better_metric_is_the_lowest():
    """``differs_across`` on LPIPS: A has the lowest LPIPS on both scenes, so one method dominates."""
    lpips = {("A", "s1", "LPIPS"): 0.10, ("B", "s1", "LPIPS"): 0.20, ("C", "s1", "LPIPS"): 0.30,
             ("A", "s2", "LPIPS"): 0.10, ("B", "s2", "LPIPS"): 0.30, ("C", "s2", "LPIPS"): 0.20}  # fmt: skip

    result = differs_across(Scenes(lpips), ["A", "B", "C"], metric="LPIPS")
    assert result.status == FAILED and result.detail == "s1: A, s2: A"


def test_motion_specs_recheck_psnr_claims_on_the_dynamic_region():
    spec = get_spec("tab03")
    assert spec.motion
    claims = spec.checked_claims()
    twins = [c for c in claims if c.id.endswith("-dynamic")]
    assert twins and all(c.args["metric"] == "PSNR dynamic" for c in twins)
    assert len(claims) == len(spec.claims) + len(twins)
    # claims on other metrics get no twin
    assert Claim("x", "t", "better", {"a": "A", "b": "B", "metric": "SSIM"}).on_dynamic_region() is None
    assert not get_spec("tab05").motion and get_spec("tab05").checked_claims() == list(
        get_spec("tab05").claims
    )


def test_no_dynamic_twin_where_the_paper_says_otherwise_about_motion():
    """Sec. IV-B: the E-D3DGS-based MoDE variants lose on the full image yet "still improve dynamic
    regions"; Sec. IV-C (iv): the static expert adds little where things move. Those claims get no
    twin; the paper's own dynamic claims are checked instead."""
    twins = lambda sid: {c.id for c in get_spec(sid).checked_claims() if c.id.endswith("-dynamic")}  # noqa: E731
    assert "mode-4dgs-dynamic" in twins("tab02") and "mode-ed3dgs-no-gain-dynamic" not in twins("tab02")
    assert "n3-beats-n2-mcmc-dynamic" not in twins("tab10")
    assert {"n3-beats-n2-ed3dgs-dynamic", "ed3dgs-beats-mcmc-dynamic"} <= twins("tab10")
    gains = [c for c in get_spec("fig_mode_tradeoff").claims if c.id.startswith("dynamic-gain")]
    assert {c.args["a"] for c in gains} == {"E-D3DGS w/ 4DGaussians", "E-D3DGS w/ Grid4D"}
    assert Claim("x", "t", "better", {"a": "A", "b": "B"}, twin=False).on_dynamic_region() is None


def test_claim_sources_use_the_papers_section_numbers():
    """``paper/moe-gs-mode.tex``: Experiments is Sec. IV (B: MoDE, C: MoE-GS, D: the comparison)."""
    sources = {c.source for sid in list_specs() for c in get_spec(sid).claims}
    assert not [s for s in sources if "Sec. V" in s or "Sec. VI" in s]
    assert {"Sec. IV-B, Quantitative", "Sec. IV-C (ii)", "Sec. IV-D (ii)"} <= sources


def test_winner_coherence_separates_regions_from_noise():
    regions = torch.zeros(3, 48, 64)
    regions[0, :, :20], regions[1, :, 20:40], regions[2, :, 40:] = 1.0, 1.0, 1.0
    assert winner_coherence(regions) == 1.0
    noise = torch.rand(3, 48, 64, generator=torch.Generator().manual_seed(0))
    assert 0.3 < winner_coherence(noise) < 0.6  # random winners: about half agree with their 5x5 majority


def test_region_shares_count_winners_inside_and_outside_the_mask():
    gates = torch.zeros(2, 10, 10)
    gates[0, :, :5], gates[1, :, 5:] = 1.0, 1.0
    mask = torch.zeros(10, 10)
    mask[:, 5:8] = 1.0  # the dynamic region lies inside expert 1's half
    shares = region_shares(gates, mask)
    assert shares["dynamic"] == [0.0, 1.0]
    assert shares["static"] == pytest.approx([50 / 70, 20 / 70])


def test_the_best_expert_map_is_the_lowest_error_everywhere_and_in_each_region():
    from bench.cells.bestmap import spatial_winners

    errors = torch.full((3, 10, 10), 0.5)
    errors[0, :, :4] = 0.1  # "a" has the lowest error on the left, "b" in the middle, "c" on the right
    errors[1, :, 4:8] = 0.1
    errors[2, :, 8:] = 0.1
    mask = torch.zeros(10, 10)
    mask[:, :2] = 1.0  # the dynamic region lies inside a's part
    where = spatial_winners(errors, mask, ["a", "b", "c"])
    assert where["winner"][0].tolist() == [0] * 4 + [1] * 4 + [2] * 2
    assert where["shares"] == pytest.approx({"a": 0.4, "b": 0.4, "c": 0.2})
    assert where["winners"] == 3 and where["coherence"] > 0.6
    assert where["region_shares"]["dynamic"] == [1.0, 0.0, 0.0]
    assert where["region_shares"]["static"] == pytest.approx([20 / 80, 40 / 80, 20 / 80])
    errors[2, :, 9] = 0.5  # a three-way tie goes to the first expert; no mask, no regions
    tied = spatial_winners(errors, None, ["a", "b", "c"])
    assert tied["winner"][0, 9] == 0 and tied["shares"]["c"] == pytest.approx(0.1)
    assert tied["region_shares"] is None


def test_the_routing_signal_averages_each_regions_winner_shares_over_views():
    from bench.cells.moe import routing_signal

    class Masked:
        def __init__(self, mask):
            self._mask = mask

        def mask(self):
            return self._mask

    mask = torch.zeros(8, 8)
    mask[:, :2] = 1.0  # the dynamic region: 16 of 64 pixels
    gates = torch.zeros(2, 8, 8)
    gates[0, :, :2] = 1.0  # expert 0 wins the dynamic region
    gates[1, :, 2:] = 1.0  # expert 1 the static one
    flipped = gates.flip(0)
    signal = routing_signal([gates, flipped, gates], [Masked(mask), Masked(mask), Masked(None)])
    assert signal["views"] == 3 and signal["coherence"] == pytest.approx(1.0)
    assert signal["dynamic_share"] == pytest.approx([0.5, 0.5])  # the two masked views, averaged
    one = routing_signal([gates], [Masked(mask)])
    assert one["dynamic_share"] == pytest.approx([1.0, 0.0]) and one["static_share"] == pytest.approx(
        [0.0, 1.0]
    )


def test_report_states_how_much_motion_the_experts_reproduce():
    from bench.report import motion_lines

    rows = [
        {"scene": "synthetic:n3v_like", "expert": "fourdgs", "motion_r2": 0.08},
        {"scene": "synthetic:n3v_like", "expert": "stg", "motion_r2": 0.36},
        {"scene": "dnerf:mutant", "expert": "grid4d", "motion_r2": None},
    ]
    (line,) = motion_lines(rows)
    assert "synthetic:n3v_like" in line and "0.08 (fourdgs) to 0.36 (stg)" in line
    assert motion_lines([rows[2]]) == []


def test_report_scores_each_motion_regime_of_the_stand_ins():
    from bench.cells._eval import REGIME_PREFIX
    from bench.report import regime_markdown
    from bench.signals import regime_psnrs

    metrics = {"psnr": 25.0, f"{REGIME_PREFIX}articulated": 21.5, f"{REGIME_PREFIX}transient": 14.25}
    assert regime_psnrs(metrics) == {"articulated": 21.5, "transient": 14.25}
    row = {"scene": "synthetic:n3v_like", "dataset": "n3v", "expert": "stg", "psnr": {"dynamic": 19.0}}
    lines = regime_markdown([{**row, "psnr_regimes": regime_psnrs(metrics)}])
    assert "| scene | dataset recipe | expert | PSNR dynamic | articulated | transient |" in lines
    assert "| synthetic:n3v_like | n3v | stg | 19.00 | 21.50 | 14.25 |" in lines
    assert regime_markdown([{**row, "psnr_regimes": {}}]) == []  # real scenes: no regimes, no table


def test_report_scores_each_held_out_camera_of_a_real_multi_camera_scene():
    from bench.report import camera_markdown
    from bench.signals import per_camera_psnr

    views = [
        {"key": f"panoptic:basketball/{cam}/{frame:06d}.jpg@160x90", "camera": cam, "psnr": psnr}
        for cam, frame, psnr in ((0, 0, 10.0), (0, 1, 12.0), (10, 0, 25.0), (10, 1, 27.0))
    ]
    assert per_camera_psnr(views) == {"0": 11.0, "10": 26.0}
    # one held-out camera (N3V's cam00, D-NeRF's monocular test split): nothing to break down
    assert per_camera_psnr([{"key": "n3v:coffee/cam00/3@100x75", "camera": 0, "psnr": 30.0}]) == {}
    row = {"scene": "panoptic:basketball", "expert": "grid4d", "psnr": {"full": 18.5}}
    lines = camera_markdown([{**row, "psnr_cameras": per_camera_psnr(views)}])
    assert "| expert | PSNR | camera 0 | camera 10 |" in lines
    assert "| grid4d | 18.50 | 11.00 | 26.00 |" in lines
    assert camera_markdown([{**row, "psnr_cameras": {}}]) == []


def test_report_states_what_the_cells_cost():
    from bench.report import compute_markdown
    from bench.signals import _build_label

    assert _build_label({"kind": "expert", "params": {"expert": "stg"}}) == "stg"
    router = {"kind": "moe", "params": {"experts": ["ex4dgs", "stg"], "router": "pixel"}}
    assert _build_label(router) == "pixel router: ex4dgs+stg"
    student = {"kind": "distill", "params": {"student": "ed3dgs", "teacher": ["ex4dgs", "stg"]}}
    assert _build_label(student) == "ed3dgs from ex4dgs+stg"
    mode = {"kind": "mode", "params": {"experts": ["fourdgs", "grid4d"]}}
    assert _build_label(mode) == "MoDE: fourdgs+grid4d"
    compute = {
        "builds": [{"kind": "expert", "what": "stg", "count": 2, "minutes": 3.0}],
        "evaluations": [{"kind": "moe", "count": 4, "minutes": 0.5}],
        "minutes": 3.5,
    }
    lines = compute_markdown(compute)
    assert "## What the cells cost" in lines and "| expert | stg | 2 | 3.0 |" in lines
    assert "| moe | 4 | 0.5 |" in lines and any("**3.5 minutes**" in line for line in lines)
    assert compute_markdown({}) == [] and compute_markdown({"builds": [], "evaluations": []}) == []


def test_tables_of_scenes_without_a_stability_run_average_several_seeds_and_judge_claims_by_their_spread(
    tmp_path, monkeypatch
):
    from dataclasses import replace

    import bench.plan
    from bench.latex import caption
    from bench.presets import get_preset
    from bench.report import noise_markdown
    from bench.signals import noise_for, run_noise, seed_noise
    from bench.store import Workspace
    from bench.values import SpecValues

    monkeypatch.setattr(bench.plan, "resolve_scenes", staged_scenes("panoptic:basketball"))
    quick = get_preset("quick")
    plan = bench.plan.make_plan(["tab16", "tab09", "fig_gates_panoptic"], quick)
    tab16, tab09, figure = plan.specs
    assert {s.seed for s in tab16.slots} == {0, 1, 2} and tab16.averaged_seeds() == {
        "panoptic:basketball": [0, 1, 2]
    }
    assert {s.seed for s in figure.slots} == {0}  # figures draw seed 0 only
    assert tab09.averaged_seeds() == {}  # a stability run prints min / max / average, not a mean
    # a stand-in that no stability run trains (the D-NeRF-like one of HyperNeRF's Table XIV) gets its own
    # seeds; the N3V stand-in's tables train once, Table IX measures its spread
    assert bench.plan.stability_scenes(quick) == {"synthetic:n3v_like"}
    tab14, tab04, tab03 = bench.plan.make_plan(["tab14", "tab04", "tab03"], quick).specs
    assert tab14.averaged_seeds() == {"synthetic:dnerf_like": [0, 1, 2]}
    assert {s.seed for s in tab04.slots} == {0} and tab04.averaged_seeds() == {}
    # unless the preset asks a table for more (quick: the N3V stand-in's paired tables)
    assert quick.table_seeds["tab03"] == 3 and tab03.averaged_seeds() == {"synthetic:n3v_like": [0, 1, 2]}
    standard = bench.plan.make_plan(["tab16"], get_preset("standard")).specs[0]
    assert {s.seed for s in standard.slots} == {0}
    # the number of seeds chooses cells; it is not part of any cell's key
    assert replace(quick, scene_seeds=7).to_dict() == quick.to_dict()

    ws = Workspace(tmp_path)
    psnr = {
        "4DGaussians": (18.0, 19.0, 20.5),
        "Grid4D": (21.0, 22.0, 21.5),
        "MoE-GS (N=2)": (22.0, 21.5, 22.5),
    }
    for slot in tab16.slots:
        write_ok_result(ws, slot.task, psnr=psnr[slot.row][slot.seed])
    for slot in tab09.slots:  # the stand-in's stability runs: 0.5 dB apart at most
        write_ok_result(ws, slot.task, psnr=25.0 + 0.25 * slot.seed)
    noise = seed_noise(plan, ws)
    basketball = noise["scenes"]["panoptic:basketball"]
    assert basketball["real"] and basketball["seeds"] == 3 and basketball["source"] == ["tab16"]
    assert basketball["rows"]["4DGaussians"]["PSNR"] == pytest.approx(2.5)
    assert basketball["metrics"]["PSNR"] == pytest.approx(2.5)
    assert noise["metrics"]["PSNR"] == pytest.approx(0.5) and noise["source"] == ["tab09"]
    # each table is judged against its own scenes' spread; a scene without repeated seeds gets the stand-ins'
    assert noise_for(noise, ["panoptic:basketball"])["PSNR"] == pytest.approx(2.5)
    assert noise_for(noise, ["synthetic:other_like"])["PSNR"] == pytest.approx(0.5)
    assert noise_for({}, ["panoptic:basketball"]) == {}

    values = SpecValues(tab16, ws, noise_for(noise, ["panoptic:basketball"]))
    assert values.get("MoE-GS (N=2)", "Basketball", "PSNR") == pytest.approx(22.0)  # the mean of 3 seeds
    statuses = {c.id: evaluate(c, values).status for c in tab16.spec.claims}
    assert statuses == {"n2-every-scene": NOISE, "n2-best-average": NOISE}  # 0.25 dB over Grid4D < 2.5 dB
    assert "Mean over seeds: panoptic:basketball 0-2" in caption(values, quick)
    lines = noise_markdown(noise)
    assert any(line.startswith("| panoptic:basketball | 3 | tab16 | 4DGaussians 2.50") for line in lines)
    assert any("(stand-in) | 3 | tab09 |" in line for line in lines)

    # standard trains basketball once: its claims borrow the quick run's spread there, and say so
    standard_plan = bench.plan.make_plan(["tab16"], get_preset("standard"))
    assert seed_noise(standard_plan, ws)["scenes"] == {}
    borrowed = run_noise(standard_plan, ws)
    assert borrowed["scenes"]["panoptic:basketball"]["preset"] == "quick"
    assert noise_for(borrowed, ["panoptic:basketball"])["PSNR"] == pytest.approx(2.5)
    assert any("| tab16 (quick run) |" in line for line in noise_markdown(borrowed))
    # quick32 loads basketball as quick does and borrows its spread; its 32-frame N3V stand-in is another
    # scene under the same name and borrows nothing
    longer = run_noise(bench.plan.make_plan(["tab16", "tab09"], get_preset("quick32")), ws)["scenes"]
    assert longer["panoptic:basketball"]["preset"] == "quick" and "synthetic:n3v_like" not in longer
    # on a machine without the quick cells (a fresh standard run), the committed quick summary's spread
    summary = tmp_path / "reports" / "summary.json"
    summary.parent.mkdir()
    summary.write_text(
        json.dumps({"header": {"git": {"commit": "abcdef0123"}}, "noise": {**noise, "preset": "quick"}})
    )
    fresh = Workspace(tmp_path / "fresh")

    def borrows_from_summary(plan, scene, source, spread):
        """``plan``, run where none of its cells measured ``scene``'s spread, takes the summary's, marked."""
        assert run_noise(plan, fresh)["scenes"] == {}
        noise = run_noise(plan, fresh, summary)
        assert noise["scenes"][scene]["committed"] == "summary.json at git abcdef0"
        assert noise_for(noise, [scene])["PSNR"] == pytest.approx(spread)
        marked = f"| {source} (quick run, summary.json at git abcdef0) |"
        assert any(marked in line for line in noise_markdown(noise))

    borrows_from_summary(standard_plan, "panoptic:basketball", "tab16", 2.5)
    assert run_noise(standard_plan, fresh, tmp_path / "nowhere.json")["scenes"] == {}
    # a quick run of a few tables (tox -e repro-tab3) has no stability run: the committed quick spread of
    # its N3V stand-in (Table IX's) judges its claims, and the report says where it comes from
    borrows_from_summary(bench.plan.make_plan(["tab03"], quick), "synthetic:n3v_like", "tab09", 0.5)

    # the same cells run elsewhere (other rounding: other values) pool: the larger spread decides
    elsewhere = Workspace(tmp_path / "elsewhere")
    for slot in tab16.slots:
        write_ok_result(elsewhere, slot.task, psnr=20.0 + 0.1 * slot.seed)  # 0.2 dB apart
    for slot in tab09.slots:
        write_ok_result(elsewhere, slot.task, psnr=25.0)
    pooled = run_noise(plan, elsewhere, summary)
    entry = pooled["scenes"]["panoptic:basketball"]
    assert entry["own_metrics"]["PSNR"] == pytest.approx(0.2) and entry["metrics"]["PSNR"] == pytest.approx(
        2.5
    )
    assert entry["pooled_with"] == "summary.json at git abcdef0"
    assert noise_for(pooled, ["panoptic:basketball"])["PSNR"] == pytest.approx(2.5)
    assert pooled["metrics"]["PSNR"] == pytest.approx(0.5)  # the stand-ins' fallback follows the pooling
    pooled_rows = [line for line in noise_markdown(pooled) if "pooled with" in line]
    assert len(pooled_rows) == 2 and "(this run's own largest: 0.20)" in pooled_rows[0]
    # a warm re-run, reading the summary that run wrote, judges as it did
    again = tmp_path / "again.json"
    again.write_text(json.dumps({"header": {"git": {"commit": "1234567"}}, "noise": pooled}))
    rerun = run_noise(plan, elsewhere, again)["scenes"]["panoptic:basketball"]
    assert rerun["metrics"]["PSNR"] == pytest.approx(2.5) and rerun["own_metrics"]["PSNR"] == pytest.approx(
        0.2
    )
    # other cells (other code, configs or seeds) never pool, and a run read back with itself is unchanged
    other_cells = json.loads(summary.read_text())
    for scene in other_cells["noise"]["scenes"].values():
        scene["cells"] = "another digest"
    again.write_text(json.dumps(other_cells))
    assert run_noise(plan, elsewhere, again)["scenes"] == seed_noise(plan, elsewhere)["scenes"]
    assert run_noise(plan, ws, summary)["scenes"] == seed_noise(plan, ws)["scenes"]


def test_a_table_judged_over_several_scenes_takes_the_largest_spread_among_them():
    from bench.signals import noise_for

    noise = {
        "metrics": {"PSNR": 0.1},
        "scenes": {"s1": {"metrics": {"PSNR": 0.5}}, "s2": {"metrics": {"PSNR": 0.2}}},
    }
    assert noise_for(noise, ["s1", "s2"]) == {"PSNR": 0.5}
    assert noise_for(noise, ["s2", "s1"]) == {"PSNR": 0.5}
    assert noise_for(noise, ["s2", "s3"]) == {"PSNR": 0.2}  # s3 has none of its own: the stand-ins' 0.1


def test_a_table_trained_once_measures_no_spread(tmp_path):
    """One seed per cell is no evidence of the noise: the scene keeps borrowing a measured spread instead of
    being judged against zero."""
    import bench.plan
    from bench.presets import get_preset
    from bench.signals import seed_noise
    from bench.store import Workspace

    plan = bench.plan.make_plan(["tab04"], get_preset("quick"))
    assert {s.seed for s in plan.specs[0].slots} == {0}
    ws = Workspace(tmp_path)
    computed = [slot for slot in plan.specs[0].slots if slot.task is not None]  # not the external rows
    assert computed
    for i, slot in enumerate(computed):
        write_ok_result(ws, slot.task, psnr=25.0 + 0.1 * i)
    assert seed_noise(plan, ws) == {"preset": "quick", "scenes": {}, "metrics": {}, "source": []}


def test_deltas_are_ours_minus_the_papers_on_comparable_cells_only(tmp_path, monkeypatch):
    import bench.plan
    from bench.presets import get_preset
    from bench.store import Workspace
    from bench.values import SpecValues

    monkeypatch.setattr(bench.plan, "resolve_scenes", staged_scenes("panoptic:basketball"))
    quick = get_preset("quick")
    real, stand_in = bench.plan.make_plan(["tab16", "tab06"], quick).specs
    ws = Workspace(tmp_path)
    for sp in (real, stand_in):
        for slot in sp.slots:
            if slot.task is not None:
                write_ok_result(ws, slot.task, psnr=20.0)
    values = SpecValues(real, ws)
    deltas = values.deltas()
    assert deltas and all(d["ours"] == pytest.approx(20.0) for d in deltas)
    for d in deltas:
        assert d["delta"] == pytest.approx(20.0 - values.paper.get(d["row"], d["column"], d["metric"]))
    assert [abs(d["delta"]) for d in deltas] == sorted((abs(d["delta"]) for d in deltas), reverse=True)
    # a stand-in's numbers are ours alone: no paper value beside them, no delta, though the paper prints
    # one in the same cell of Table VI (its metric columns average the N3V scenes)
    on_stand_in = SpecValues(stand_in, ws)
    measured = on_stand_in.measured()
    assert measured and all(m["paper"] is None for m in measured)
    assert any(on_stand_in.paper.get(m["row"], m["column"], m["metric"]) is not None for m in measured)
    assert on_stand_in.deltas() == []


class PrintedView(View):
    """A view whose columns print one metric each, as a table whose columns are metrics does."""

    def __init__(self, values: dict, printed: dict[str, str]) -> None:
        super().__init__(values)
        self.printed = printed

    def metrics_of(self, column):
        return [self.printed[column]]


def test_details_name_the_metric_where_the_column_prints_another():
    """A dynamic-region twin compares "PSNR dynamic" under Table X's "PSNR (dB)" column: its detail must
    not read as full-image PSNR."""
    col = "PSNR (dB)"
    v = PrintedView(
        {("a", col, "PSNR"): 30.0, ("b", col, "PSNR"): 28.3, ("a", col, "PSNR dynamic"): 24.4,
         ("b", col, "PSNR dynamic"): 21.7},
        {col: "PSNR"},
    )  # fmt: skip
    twin = better(v, "a", "b", metric="PSNR dynamic", columns=[col])
    assert twin.status == HELD and "PSNR (dB) [PSNR dynamic]: 24.4 vs b 21.7" in twin.detail
    plain = better(v, "a", "b", columns=[col])
    assert "PSNR (dB): 30 vs b 28.3" in plain.detail and "[" not in plain.detail
    assert "PSNR (dB) [PSNR dynamic]: |24.4 - 21.7|" in within(v, "a", "b", 1.0, "PSNR dynamic", [col]).detail


@pytest.mark.parametrize(
    ("a", "b", "leans"),
    [(28.2, 28.0, WITH_PAPER), (27.9, 28.0, AGAINST_PAPER), (28.0, 28.0, AGAINST_PAPER)],
)
def test_an_undecided_claim_says_which_way_it_leans(a, b, leans):
    """The lean is the verdict of the same comparisons at zero noise (a tie fails a strict claim)."""
    claim = Claim("c", "A beats B", "better", {"a": "A", "b": "B"})
    result = evaluate(claim, View(psnr(A=a, B=b), {"PSNR": 0.3}))
    assert (result.status, result.leans) == (NOISE, leans)
    assert result.verdict == f"within noise, {leans}"
    decided = evaluate(claim, View(psnr(A=29.0, B=28.0), {"PSNR": 0.3}))
    assert (decided.status, decided.leans, decided.verdict) == (HELD, None, HELD)


def test_within_and_monotone_lean_too():
    kept = Claim("c", "pruning keeps PSNR", "within", {"a": "A", "b": "B", "tolerance": 0.1})
    assert evaluate(kept, View(psnr(A=30.0, B=30.25), {"PSNR": 0.2})).leans == AGAINST_PAPER
    falls = Claim("m", "more is worse", "monotone", {"rows": ["A"], "columns": ["1", "2"]})
    steps = View({("A", c, "PSNR"): x for c, x in (("1", 30.0), ("2", 30.1))}, {"PSNR": 0.2})
    assert evaluate(falls, steps).leans == AGAINST_PAPER


def test_claim_counts_say_how_many_undecided_claims_go_against_the_paper():
    claims = [
        {"ours": HELD},
        {"ours": NOISE, "ours_leans": AGAINST_PAPER},
        {"ours": NOISE, "ours_leans": WITH_PAPER},
        {"ours": NOISE, "ours_leans": AGAINST_PAPER},
        {"ours": NA},
    ]
    assert claim_counts(claims) == "1 held / 0 failed / 3 within noise (2 against the paper) / 1 n/a"
    assert claim_counts([{"ours": NOT_JUDGED}]) == "0 held / 0 failed / 0 within noise / 1 not judged"
    assert verdict(claims[1]) == "within noise, against the paper" and verdict(claims[0]) == HELD


def test_a_run_without_any_seed_spread_judges_no_claim(tmp_path, monkeypatch):
    """At ``tiny`` (one seed, nothing to borrow) every claim reads "not judged" with the reason, while the
    paper's own numbers are still checked."""
    from bench.plan import make_plan
    from bench.presets import get_preset
    from bench.report import NO_BASIS, spec_report
    from bench.store import Workspace
    from bench.values import SpecValues

    plan = make_plan([get_spec("tab17")], get_preset("tiny"))
    values = SpecValues(plan.specs[0], Workspace(tmp_path), noise={})
    report = spec_report(values, get_preset("tiny"))
    assert report.claims and {c["ours"] for c in report.claims} == {NOT_JUDGED}
    assert all(c["ours_detail"] == NO_BASIS for c in report.claims)
    assert {c["paper"] for c in report.claims} <= {HELD, FAILED, NA}


def test_claims_have_a_kind_and_reports_count_each_apart():
    """Dynamic-region twins are the suite's; cost and implementation checks are sanity checks, never
    counted with the paper's claims."""
    kinds = {c.id: c.kind for sid in list_specs() for c in get_spec(sid).checked_claims()}
    assert kinds["n2-every-scene-dynamic"] == "suite" and kinds["n2-every-scene"] == "paper"
    assert kinds["prune-memory"] == kinds["single-pass-same-image"] == kinds["mode-modest-cost"] == "sanity"
    with pytest.raises(ValueError, match="kind must be one of"):
        Claim("x", "x", "better", kind="ours")
    claims = [{"ours": HELD, "kind": "sanity"}, {"ours": NOISE, "ours_leans": WITH_PAPER}, {"ours": FAILED}]
    assert claims_by_kind(claims) == (
        "paper: 0 held / 1 failed / 1 within noise (0 against the paper); "
        "sanity checks: 1 held / 0 failed / 0 within noise"
    )


def test_the_html_report_is_the_markdown_report_with_contents():
    """REPORT.html renders REPORT.md itself: the same sections (a contents list links each), the same
    tables, and every table's values ours | paper | Δ."""
    import re

    from bench.report import render_html, values_markdown

    values = [
        {"row": "MoE-GS", "column": "Mutant", "metric": "PSNR", "ours": 40.0, "paper": 44.11},
        {"row": "Grid4D", "column": "Mutant", "metric": "PSNR", "ours": 38.5, "paper": None},
    ]
    table = values_markdown(values)
    assert table[:2] == ["| row | Mutant PSNR |", "|---|---|"]
    assert table[2] == "| MoE-GS | 40 · paper 44.11 (Δ -4.11) |" and table[3] == "| Grid4D | 38.5 |"
    summary = ["## Summary", "", "| a | b |", "|---|---|", "| 1 | 2 |", ""]
    section = ["## tab17: D-NeRF", "", *table, "### detail", "", "![f](f.png)", "", "### detail"]
    md = "\n".join(["# report", "", *summary, *section])
    page = render_html(md)
    sections = re.findall(r"^#{2,3} (.+)$", md, flags=re.M)
    assert re.findall(r"<h[23] id=\"[^\"]+\">(.+?)</h[23]>", page) == sections
    assert [f"href='#{a}'" in page for a in ("summary", "tab17-d-nerf", "detail", "detail-2")] == [True] * 4
    assert page.count("<table>") == 2 and "40 · paper 44.11 (Δ -4.11)" in page
    assert '<img src="f.png" alt="f"' in page


def test_a_comparison_is_judged_against_its_rows_own_spreads():
    """Two rows that measured their own spread are compared against the larger of the two, not against
    the largest row of the scene; a row without one falls back to the scene-wide spread."""
    view = View(psnr(A=28.5, B=28.0, C=28.0), {"PSNR": 0.9})
    view.row_noise = {("A", "PSNR"): 0.1, ("B", "PSNR"): 0.3}
    assert better(view, "A", "B").status == HELD  # 0.5 dB beyond the rows' 0.3
    assert better(view, "A", "C").status == NOISE  # C has no spread of its own: the scene's 0.9
    assert "seed spread 0.3" in better(view, "A", "B").detail
    assert within(view, "A", "B", tolerance=0.25).status == NOISE  # |0.5| - 0.25 < 0.3


def test_two_rows_trained_with_the_same_seeds_are_judged_against_their_paired_spread():
    """The spread of the per-seed difference of two rows (which shared experts or seeds make smaller than
    either row's own spread) decides their comparison; other comparisons keep the rows' spreads."""
    view = View(psnr(A=28.5, B=28.3, C=28.0), {"PSNR": 0.9})
    view.row_noise = {("A", "PSNR"): 0.6, ("B", "PSNR"): 0.6, ("C", "PSNR"): 0.6}
    view.pair_noise = {("A", "B", "PSNR"): 0.1}
    assert better(view, "A", "B").status == HELD and "paired spread 0.1" in better(view, "A", "B").detail
    assert better(view, "B", "A").status == FAILED  # the pair is unordered
    assert better(view, "A", "C").status == NOISE and "seed spread 0.6" in better(view, "A", "C").detail


def test_a_deterministic_quantity_is_compared_without_noise(tmp_path):
    """Memory is the trained model's size: a difference of 0.2 MB decides a claim whatever spread the
    scene or the rows measured, the detail says so, and a run with no spread at all still judges it."""
    from bench.plan import make_plan
    from bench.presets import get_preset
    from bench.report import spec_report
    from bench.store import Workspace
    from bench.values import SpecValues

    view = View({("A", "@mean", "Memory"): 34.6, ("B", "@mean", "Memory"): 34.8}, {"Memory": 0.33})
    view.row_noise = {("A", "Memory"): 0.5, ("B", "Memory"): 0.5}
    view.pair_noise = {("A", "B", "Memory"): 0.4}
    result = better(view, "A", "B", metric="Memory")
    assert result.status == HELD and "exact: no noise" in result.detail
    assert better(view, "B", "A", metric="Memory").status == FAILED
    assert within(view, "A", "B", tolerance=0.1, metric="Memory").status == FAILED
    plan = make_plan([get_spec("tab07")], get_preset("tiny"))
    report = spec_report(SpecValues(plan.specs[0], Workspace(tmp_path)), get_preset("tiny"))
    claims = {c["id"]: c for c in report.claims}
    assert claims["pruning-memory"]["ours"] != NOT_JUDGED  # no spread measured: memory is still judged
    assert claims["pruning-keeps-psnr"]["ours"] == NOT_JUDGED


def test_paired_spreads_come_from_the_seeds_both_rows_trained():
    from bench.signals import _paired_spreads, pair_noise_for

    def seeds(*psnrs):
        return {s: (f"k{s}", {"psnr": v}) for s, v in enumerate(psnrs)}

    per_seed = {
        ("s", "tab17", "MoE", None): seeds(30.0, 31.0, 29.0),
        ("s", "tab17", "Grid4D", None): seeds(29.8, 30.9, 28.7),  # differences 0.2, 0.1, 0.3
        ("s", "tab17", "Lone", None): {0: ("k", {"psnr": 1.0})},  # one seed: no pair
        ("t", "tab17", "MoE", None): seeds(1.0, 2.0),  # another scene
    }
    [pair] = _paired_spreads(per_seed, "s", stability=set())  # no stability run among these tables
    assert pair["rows"] == ["Grid4D", "MoE"] and pair["seeds"] == 3
    assert pair["metrics"]["PSNR"] == pytest.approx(0.2)  # 0.3 - 0.1; each row alone spans 2.2 and 2.3
    noise = {"scenes": {"s": {"pairs": [pair]}}}
    assert pair_noise_for(noise, ["s"]) == {("Grid4D", "MoE", "PSNR"): pytest.approx(0.2)}


def test_an_undecided_claim_says_how_many_seeds_would_decide_it():
    """A margin d inside a seed spread s: a mean over n seeds has a spread of about s / sqrt(n), so
    ceil((s / d)^2) seeds decide it; the claim's worst comparison counts; on the boundary none does."""
    claim = Claim("c", "A beats B", "better", {"a": "A", "b": ["B", "C"]})
    result = evaluate(claim, View(psnr(A=28.2, B=28.0, C=28.1), {"PSNR": 0.3}))
    assert result.status == NOISE and result.seeds == 9  # C: (0.3 / 0.1)^2
    assert seeds_to_decide([(0.0, 0.3)]) is None and seeds_to_decide([(0.25, 0.3)]) == 2
    row = {"ours": NOISE, "ours_leans": WITH_PAPER, "ours_seeds_to_decide": 9}
    assert verdict(row) == "within noise, with the paper (about 9 seeds per row would decide it)"
    assert verdict({**row, "ours_seeds_to_decide": None}).endswith("(it sits on the boundary)")


def test_a_paper_claim_on_timings_of_separate_cells_is_not_judged(tmp_path):
    """Table VII's FPS claims compare timings of separate cells on our CPU: not judged, with the reason;
    its memory claims (sanity checks) and image claims are."""
    from bench.plan import make_plan
    from bench.presets import get_preset
    from bench.report import UNPAIRED, spec_report
    from bench.store import Workspace
    from bench.values import SpecValues

    plan = make_plan([get_spec("tab07")], get_preset("tiny"))
    values = SpecValues(plan.specs[0], Workspace(tmp_path), noise={"PSNR": 0.1})
    claims = {c["id"]: c for c in spec_report(values, get_preset("tiny")).claims}
    assert (
        claims["single-pass-fps"]["ours"] == NOT_JUDGED
        and claims["single-pass-fps"]["ours_detail"] == UNPAIRED
    )
    assert (
        claims["pruning-memory"]["ours"] != NOT_JUDGED and claims["pruning-keeps-psnr"]["ours"] != NOT_JUDGED
    )
