"""Checkpoint files: nested state round trip (bit-exact), atomic writes, clear errors."""

import json

import pytest
import torch
from safetensors.torch import save_file

from moegs.io import load_checkpoint, save_checkpoint
from moegs.train.optim import Optimizers
from moegs.train.params import ParamGroup


def test_nested_state_round_trip_is_bit_exact(tmp_path):
    g = torch.Generator().manual_seed(0)
    state = {
        "step": 12,
        "name": "static",
        "flags": [True, None, 1.5],
        "model": {"splats.means": torch.randn(7, 3, generator=g), "ids": torch.arange(7)},
        "by_index": {0: {"exp_avg": torch.randn(2, generator=g)}, 3: "x"},
        "rng": torch.get_rng_state(),
        "empty": torch.zeros(0, 3),
        "half": torch.randn(4, generator=g).to(torch.float16),
    }
    path = save_checkpoint(tmp_path / "ckpt.safetensors", state)
    back = load_checkpoint(path)
    assert back.keys() == state.keys()
    assert back["step"] == 12 and back["name"] == "static" and back["flags"] == [True, None, 1.5]
    assert set(back["by_index"]) == {0, 3} and back["by_index"][3] == "x"
    for a, b in [
        (state["model"]["splats.means"], back["model"]["splats.means"]),
        (state["model"]["ids"], back["model"]["ids"]),
        (state["by_index"][0]["exp_avg"], back["by_index"][0]["exp_avg"]),
        (state["rng"], back["rng"]),
        (state["empty"], back["empty"]),
        (state["half"], back["half"]),
    ]:
        assert a.dtype == b.dtype and torch.equal(a, b)


def test_optimizer_state_round_trip(tmp_path):
    p = torch.nn.Parameter(torch.randn(5, 3))
    opt = Optimizers([ParamGroup("means", [p], 0.1)])
    p.grad = torch.randn(5, 3)
    opt.step()
    save_checkpoint(tmp_path / "o.safetensors", {"optim": opt.state_dict()})
    q = torch.nn.Parameter(p.detach().clone())
    other = Optimizers([ParamGroup("means", [q], 0.1)])
    other.load_state_dict(load_checkpoint(tmp_path / "o.safetensors")["optim"])
    a, b = opt.optimizers["means"].state[p], other.optimizers["means"].state[q]
    assert all(torch.equal(a[k], b[k]) for k in ("step", "exp_avg", "exp_avg_sq"))
    grad = torch.randn(5, 3)
    p.grad, q.grad = grad, grad.clone()
    opt.step()
    other.step()
    assert torch.equal(p, q)


def test_failed_write_keeps_previous_checkpoint(tmp_path):
    path = tmp_path / "ckpt.safetensors"
    save_checkpoint(path, {"step": 1, "x": torch.ones(2)})
    with pytest.raises(TypeError, match="cannot store object at bad"):
        save_checkpoint(path, {"step": 2, "bad": object()})
    assert load_checkpoint(path)["step"] == 1
    assert [p.name for p in tmp_path.iterdir()] == ["ckpt.safetensors"]  # no temporary files left


def test_errors_name_the_problem(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_checkpoint(tmp_path / "missing.safetensors")
    save_file({"x": torch.ones(1)}, tmp_path / "plain.safetensors")
    with pytest.raises(ValueError, match="not a moegs checkpoint"):
        load_checkpoint(tmp_path / "plain.safetensors")


def test_written_files_follow_the_umask(tmp_path):
    """Checkpoints and JSON files are readable by the group and others under a 022 umask (not 0600)."""
    import os
    import stat

    from moegs.io import save_checkpoint, write_json

    old = os.umask(0o022)
    try:
        paths = [
            write_json(tmp_path / "a.json", {"x": 1}),
            save_checkpoint(tmp_path / "c.safetensors", {"w": torch.ones(2)}),
        ]
    finally:
        os.umask(old)
    for path in paths:
        assert stat.S_IMODE(path.stat().st_mode) == 0o644, path


def test_views_and_repeated_tensors_are_stored_on_their_own(tmp_path):
    t = torch.arange(6.0)
    back = load_checkpoint(save_checkpoint(tmp_path / "c.safetensors", {"a": t, "b": t, "tail": t[2:]}))
    assert torch.equal(back["a"], t) and torch.equal(back["b"], t) and torch.equal(back["tail"], t[2:])


def test_what_cannot_be_stored_exactly_is_refused(tmp_path):
    with pytest.raises(TypeError, match=r"checkpoint: keys at / must be str or int, got \[True\]"):
        save_checkpoint(tmp_path / "c.safetensors", {True: 1})
    with pytest.raises(ValueError, match="Out of range float"):  # NaN is not JSON: refused, not written
        save_checkpoint(tmp_path / "c.safetensors", {"loss": float("nan")})
    assert list(tmp_path.iterdir()) == []


def test_damaged_metadata_and_json_files_name_the_file(tmp_path):
    from moegs.errors import IntegrityError
    from moegs.io import read_json

    save_file({"x": torch.ones(1)}, tmp_path / "broken.safetensors", metadata={"moegs": "{not json"})
    with pytest.raises(IntegrityError, match="broken.safetensors: damaged checkpoint metadata"):
        load_checkpoint(tmp_path / "broken.safetensors")
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(IntegrityError, match="list.json: expected a JSON object, got list"):
        read_json(tmp_path / "list.json")
    (tmp_path / "latin1.json").write_bytes(b'{"name": "\xe9"}')
    with pytest.raises(IntegrityError, match="latin1.json: not valid JSON"):
        read_json(tmp_path / "latin1.json")


def test_a_changed_byte_anywhere_is_refused_and_old_files_still_read(tmp_path):
    """The content digest written with a checkpoint catches a flipped bit in a tensor and an edited value
    in its JSON; a file from before digests (moegs metadata, no digest) reads as it is."""
    from moegs.errors import IntegrityError

    path = save_checkpoint(tmp_path / "ckpt.safetensors", {"step": 3, "w": torch.arange(64.0)})
    raw = path.read_bytes()
    flipped = bytearray(raw)
    flipped[-9] ^= 0x01  # inside the last tensor's data
    (tmp_path / "flipped.safetensors").write_bytes(bytes(flipped))
    with pytest.raises(IntegrityError, match="flipped.safetensors: its content does not match the digest"):
        load_checkpoint(tmp_path / "flipped.safetensors")
    edited = raw.replace(b'\\"step\\": 3', b'\\"step\\": 7')  # the JSON sits escaped in the header
    assert edited != raw and len(edited) == len(raw)
    (tmp_path / "edited.safetensors").write_bytes(edited)
    with pytest.raises(IntegrityError, match="edited.safetensors: its content does not match the digest"):
        load_checkpoint(tmp_path / "edited.safetensors")
    meta = json.dumps({"step": 3, "w": {"__tensor__": "w"}})
    save_file({"w": torch.arange(4.0)}, tmp_path / "old.safetensors", metadata={"moegs": meta})
    assert load_checkpoint(tmp_path / "old.safetensors")["step"] == 3


def test_a_failed_json_write_leaves_no_temporary_file(tmp_path):
    from moegs.io import write_json

    write_json(tmp_path / "a.json", {"ok": 1})
    with pytest.raises(TypeError, match="not JSON serializable"):
        write_json(tmp_path / "a.json", {"bad": object()})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]
    assert json.loads((tmp_path / "a.json").read_text()) == {"ok": 1}
