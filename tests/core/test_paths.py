"""``moegs.paths.data_root``: ``MOEGS_DATA``, else ``../shared/data`` beside the repository, else none."""

from __future__ import annotations

from moegs import paths


def test_data_root_is_the_env_then_the_shared_folder_then_none(tmp_path, monkeypatch):
    repo = tmp_path / "repo"
    repo.mkdir()
    monkeypatch.setattr(paths, "_REPO", repo)
    monkeypatch.delenv("MOEGS_DATA", raising=False)
    assert paths.data_root() is None  # no ../shared/data: say so rather than name a missing folder
    (tmp_path / "shared" / "data").mkdir(parents=True)
    assert paths.data_root() == tmp_path / "shared" / "data"
    monkeypatch.setenv("MOEGS_DATA", str(tmp_path / "elsewhere"))
    assert paths.data_root() == tmp_path / "elsewhere"
