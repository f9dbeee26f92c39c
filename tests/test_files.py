"""files: folder lock, stray temp files of killed writers, content hashes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest

from drivee2e_jax.files import (
    LOCK_NAME,
    FolderLocked,
    atomic_write_text,
    is_stray_temp_file,
    lock_folder,
    remove_stray_temp_files,
    sha256_tree,
)

#: A process that holds the folder lock (as another `drivee2e bench` would) until killed.
HOLDER = textwrap.dedent("""
    import sys, time
    from drivee2e_jax.files import lock_folder
    with lock_folder(sys.argv[1], command="drivee2e bench --policy other"):
        print("locked", flush=True)
        time.sleep(60)
""")


def test_a_second_holder_is_refused_with_one_line_naming_the_first(tmp_path):
    folder = tmp_path / "run"
    with lock_folder(folder, command="drivee2e bench --policy a"):
        assert (folder / LOCK_NAME).is_file()
        with pytest.raises(FolderLocked) as e, lock_folder(folder, hint="use another --out"):
            pass
        msg = str(e.value)
        assert "\n" not in msg and "in use by another run" in msg and f"pid {os.getpid()}" in msg
        assert "drivee2e bench --policy a" in msg and msg.endswith("use another --out")
    with lock_folder(folder):  # released: free again, and the stale record is gone
        pass
    assert (folder / LOCK_NAME).read_text() == ""


def test_the_lock_of_another_process_blocks_until_it_is_killed(tmp_path):
    folder = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "locked"
        with pytest.raises(FolderLocked, match=rf"pid {proc.pid} on .*drivee2e bench --policy other"), \
                lock_folder(folder):
            pass
    finally:
        proc.send_signal(signal.SIGKILL)  # the kernel drops its flock: no stale lock
        proc.wait()
    with lock_folder(folder):
        pass


def test_temp_files_of_a_killed_writer_are_found_and_removed(tmp_path):
    target = tmp_path / "policies" / "p.json"
    kill = ("import os, signal, sys; from pathlib import Path; from drivee2e_jax.files import atomic_write; "
            "atomic_write(Path(sys.argv[1]), lambda f: (f.write('{\"half'), f.flush(), "
            "os.kill(os.getpid(), signal.SIGKILL)))")
    assert subprocess.run([sys.executable, "-c", kill, str(target)]).returncode == -signal.SIGKILL
    left = list(target.parent.iterdir())
    assert len(left) == 1 and is_stray_temp_file(left[0]) and left[0].name.startswith(".p.json.")
    atomic_write_text(tmp_path / "keep.tmp", "not a temp file of atomic_write")  # no leading dot: kept
    (tmp_path / ".lock").write_text("")
    assert remove_stray_temp_files(tmp_path) == left
    assert sorted(p.name for p in tmp_path.rglob("*")) == [".lock", "keep.tmp", "policies"]


def test_tree_hash_follows_content_not_place_or_time(tmp_path):
    a = tmp_path / "ckpt"
    (a / "sub").mkdir(parents=True)
    (a / "sub" / "w.bin").write_bytes(b"\x00\x01")
    (a / "meta.json").write_text("{}")
    h = sha256_tree(a)
    os.utime(a / "meta.json", (1, 1))
    b = tmp_path / "moved"
    a.rename(b)
    assert sha256_tree(b) == h
    (b / "sub" / "w.bin").write_bytes(b"\x00\x02")
    assert sha256_tree(b) != h
    (b / "sub" / "w.bin").write_bytes(b"\x00\x01")
    (b / "extra").write_text("")
    assert sha256_tree(b) != h
    assert sha256_tree(b / "meta.json") != sha256_tree(b / "extra")
