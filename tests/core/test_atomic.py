"""``moegs.atomic.atomic_path``: a file is replaced whole or not at all, with a plain new file's
permissions, and no temporary is left behind either way."""

from __future__ import annotations

import errno
import os
import stat

import pytest

from moegs.atomic import atomic_path, umask_mode


def _mode(path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_a_finished_block_replaces_the_file_with_the_umask_permissions(tmp_path):
    path = tmp_path / "new" / "folder" / "out.txt"
    with atomic_path(path) as tmp:
        assert tmp.parent == path.parent and tmp.is_file() and not path.exists()
        tmp.write_text("one")
    assert path.read_text() == "one" and os.listdir(path.parent) == ["out.txt"]
    assert _mode(path) == umask_mode()
    with atomic_path(path) as tmp:
        tmp.write_text("two")
        assert path.read_text() == "one"  # the old contents until the block ends
    assert path.read_text() == "two" and os.listdir(path.parent) == ["out.txt"]


def test_a_failed_block_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")
    for error in (ValueError, KeyboardInterrupt):
        with pytest.raises(error), atomic_path(path) as tmp:
            tmp.write_text("half")
            raise error
        assert path.read_text() == "old" and os.listdir(tmp_path) == ["out.txt"]


def test_a_writer_that_replaces_the_temporary_gets_the_umask_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        with atomic_path(tmp_path / "lib.so", executable=True) as tmp:
            tmp.unlink()
            fd = os.open(tmp, os.O_CREAT | os.O_WRONLY, 0o600)  # as safetensors or a linker may
            os.close(fd)
        with atomic_path(tmp_path / "data.bin") as tmp:
            tmp.chmod(0o600)
    finally:
        os.umask(old)
    assert _mode(tmp_path / "lib.so") == 0o755 and _mode(tmp_path / "data.bin") == 0o644


def test_a_full_disk_is_one_line_naming_the_file(tmp_path):
    """Writers (safetensors, numpy) report a full disk without the file's name: the error names it and the
    space left, the old file stays and no temporary is left."""
    path = tmp_path / "checkpoint.safetensors"
    path.write_text("old")
    with pytest.raises(OSError) as caught, atomic_path(path) as tmp:
        tmp.write_text("half")
        raise OSError(errno.ENOSPC, "No space left on device")
    message = str(caught.value)
    assert caught.value.errno == errno.ENOSPC and "\n" not in message
    assert message.startswith(f"cannot write {path}: no space left on its disk (") and "MiB free)" in message
    assert path.read_text() == "old" and os.listdir(tmp_path) == ["checkpoint.safetensors"]
