"""``bench.single_pass``: paired, alternating timing of one ``rasterize_multi`` against K renders."""

from __future__ import annotations

import json

import pytest

from bench import single_pass


def test_rounds_alternate_which_mode_goes_first_and_time_each_call():
    calls, now = [], [0.0]

    def clock():
        return now[0]

    def mode(name, ms):
        def run():
            calls.append(name)
            now[0] += ms / 1000

        return run

    single, separate = single_pass.paired_times(
        mode("single", 2.0), mode("separate", 5.0), rounds=4, warmup=1, clock=clock
    )
    assert calls == ["single", "separate"] * 2 + [
        "separate",
        "single",
        "single",
        "separate",
        "separate",
        "single",
    ]
    assert single == pytest.approx([2.0] * 4) and separate == pytest.approx([5.0] * 4)
    with pytest.raises(ValueError, match="rounds >= 1"):
        single_pass.paired_times(mode("a", 1), mode("b", 1), rounds=0, warmup=0)


def test_the_speed_up_is_the_median_of_per_round_ratios():
    summary = single_pass.summarise([1.0, 2.0, 1.0, 4.0, 1.0], [2.0, 2.0, 3.0, 4.0, 1.5])
    # ratios 2, 1, 3, 1, 1.5: median 1.5 (the ratio of the medians would be 2 / 1 = 2)
    assert summary["speedup"] == pytest.approx(1.5)
    assert summary["speedup_p10"] == pytest.approx(1.0) and summary["speedup_p90"] == pytest.approx(2.6)
    assert summary["single_ms"] == 1.0 and summary["separate_ms"] == 2.0 and summary["rounds"] == 5


def test_a_cpu_run_writes_json_and_a_table_with_a_column_per_repeat(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("a\n<!-- results:single-pass -->\nold\n<!-- /results:single-pass -->\nb\n")
    first, second = tmp_path / "one.json", tmp_path / "two.json"
    for out in (first, second):
        args = [
            "--backend",
            "torch",
            "--sizes",
            "200:24",
            "--rounds",
            "2",
            "--warmup",
            "0",
            "--json",
            str(out),
        ]
        assert single_pass.main(args) == 0
    result = json.loads(first.read_text())
    assert [(c["n"], c["res"], c["backward"]) for c in result["cases"]] == [(200, 24, False), (200, 24, True)]
    for case in result["cases"]:
        assert len(case["single_all_ms"]) == len(case["separate_all_ms"]) == 2 and case["speedup"] > 0
    argv = ["--from-json", "--json", str(first), "--json", str(second), "--readme", str(readme)]
    assert single_pass.main(argv) == 0
    text = readme.read_text()
    assert "old" not in text and "speed-up, run 2" in text and "2 runs" in text


def test_the_target_is_met_only_if_every_run_meets_it():
    from bench.rasterizer import SINGLE_PASS_TARGET

    def run(speedup):
        case = {"n": 5000, "res": 128, "backward": False, "speedup": speedup, "speedup_p10": speedup,
                "speedup_p90": speedup, "separate_ms": 3.0, "single_ms": 1.0}  # fmt: skip
        header = {"backend": "torch", "device": "cpu", "rounds": 10, "warmup": 1, "date": "d", "torch": "t"}
        return {"cases": [case], "experts": 3, **header}

    fast, slow = run(SINGLE_PASS_TARGET + 0.5), run(SINGLE_PASS_TARGET - 0.5)
    assert "(median): met" in single_pass.markdown(fast, [fast])
    assert "(median): MISSED" in single_pass.markdown(fast, [slow])  # a repeat below the target
    assert "(median): MISSED" in single_pass.markdown(slow, [fast])


@pytest.mark.parametrize("sizes", ["", "5000", "5000:0", "a:b", "1:2:3"])
def test_bad_sizes_are_named(sizes, capsys):
    with pytest.raises(SystemExit):
        single_pass.main(["--backend", "torch", "--sizes", sizes])
    assert "--sizes must look like 5000:128" in capsys.readouterr().err
