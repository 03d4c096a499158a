"""``quick32``: quick with 32-frame stand-ins, a diagnostic whose outputs keep their own folders."""

from __future__ import annotations

from bench.all import output_dirs
from bench.presets import get_preset
from bench.scenes import SceneRef, load_kwargs
from bench.tasks import Task

QUICK, QUICK32 = get_preset("quick"), get_preset("quick32")
STAND_IN = SceneRef("synthetic:n3v_like", "n3v", None, False)
REAL = SceneRef("dnerf:mutant", "dnerf", "Mutant", True)


def test_only_the_stand_ins_length_differs_from_quick():
    differ = {k for k, v in QUICK32.to_dict().items() if QUICK.to_dict()[k] != v}
    assert differ == {"name", "description", "synthetic_overrides"}
    assert load_kwargs(STAND_IN, QUICK32) == {"preset": "quick", "seed": 0, "overrides": {"num_frames": 32}}
    assert load_kwargs(REAL, QUICK32) == load_kwargs(REAL, QUICK)


def test_its_cells_never_mix_with_quicks():
    params = {"expert": "ex4dgs", "dataset": "n3v"}
    quick, quick32 = (Task("build", "expert", params, STAND_IN.name, {}, p) for p in ("quick", "quick32"))
    assert quick.code_version == quick32.code_version and quick.key != quick32.key


def test_a_full_run_keeps_its_own_folders(tmp_path):
    everything = ["tab02", "tab03"]
    assert output_dirs(tmp_path, QUICK32, everything, everything) == (
        tmp_path / "tables" / "quick32",
        tmp_path / "reports" / "quick32",
    )
    subset = tmp_path / "reports" / "subsets" / "quick32-tab03"
    assert output_dirs(tmp_path, QUICK32, ["tab03"], everything) == (subset / "tables", subset / "reports")
    assert output_dirs(tmp_path, QUICK, everything, everything) == (tmp_path / "tables", tmp_path / "reports")


def test_where_outputs_go_is_not_in_any_key():
    assert "own_outputs" not in QUICK32.to_dict()
    assert QUICK32.separate_outputs and not QUICK.separate_outputs and get_preset("standard").separate_outputs
    assert get_preset("tiny").separate_outputs  # a tiny run never writes over the committed quick outputs
