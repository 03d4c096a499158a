"""The API tour of ``docs/api.md`` runs as written (its ``runs/`` go to a scratch folder)."""

from __future__ import annotations

import re
from pathlib import Path

PAGE = Path(__file__).resolve().parents[2] / "docs" / "api.md"


def tour_code() -> str:
    section = PAGE.read_text().split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 1, "the tour holds exactly one python block"
    return blocks[0]


def test_api_tour_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    exec(compile(tour_code(), str(PAGE), "exec"), {"__name__": "readme_tour"})
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("synthetic:dnerf_like")
    assert re.fullmatch(r"deformable \d+\.\d\d dB", printed[1]) and printed[2].startswith("grid4d ")
    assert printed[3].startswith("torch.Size([") and printed[4].endswith(" True")
    assert (tmp_path / "runs/tour/moe").is_dir() and (tmp_path / "runs/tour/grid4d/metrics.json").is_file()
