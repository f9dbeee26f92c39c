"""files: folder lock, stray temp files of killed writers, content hashes, owned outputs, strict JSON."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest

from drivee2e_jax.files import (
    LOCK_NAME,
    DuplicateKeyError,
    FolderLocked,
    ForeignFiles,
    JSONFileError,
    OwnFolder,
    atomic_write_text,
    check_own_file,
    check_own_folder,
    is_stray_temp_file,
    loads_json,
    lock_folder,
    read_json,
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


KIND = OwnFolder("results", "run.json", ("run.json", "policies/*.json", "summary.json", "ckpt/*/**"))


def test_force_redoes_only_a_folder_of_drivee2e_files(tmp_path):
    out = tmp_path / "out"
    check_own_folder(out, KIND, redo=True)  # missing: fine
    out.mkdir()
    (out / LOCK_NAME).write_text("")
    (out / ".summary.json.abcd1234.tmp").write_text("")
    (out / "plots").mkdir()  # lock, temp files and empty folders do not count
    check_own_folder(out, KIND, redo=True)

    for name in ("report.md", "summary.json", "plots/fig.png"):  # the user's own files
        (out / name).write_text("mine")
    for redo in (False, True):
        with pytest.raises(ForeignFiles) as e:
            check_own_folder(out, KIND, redo=redo)
        msg = str(e.value)
        assert "\n" not in msg and msg.startswith(f"{out}: not a drivee2e results folder (no run.json; holds ")
        assert "plots/fig.png, report.md, summary.json" in msg and "--force" in msg

    (out / "run.json").write_text("{}")  # a results folder, with the user's files in it
    check_own_folder(out, KIND, redo=False)  # resuming deletes nothing
    with pytest.raises(ForeignFiles, match=r"holds files drivee2e did not write \(plots/fig.png, report.md\); "
                                           r"--force redoes only"):
        check_own_folder(out, KIND, redo=True)
    (out / "plots" / "fig.png").unlink()
    (out / "report.md").unlink()
    (out / "policies").mkdir()
    (out / "policies" / "a.json").write_text("{}")
    (out / "ckpt" / "3" / "state").mkdir(parents=True)
    (out / "ckpt" / "3" / "state" / "x.bin").write_text("")
    check_own_folder(out, KIND, redo=True)
    (out / "ckpt" / "notes.txt").write_text("")  # "ckpt/*/**" is below ckpt/<name>/ only
    (out / "policies" / "deep").mkdir()
    (out / "policies" / "deep" / "b.json").write_text("")  # "*" does not cross "/"
    with pytest.raises(ForeignFiles, match=r"\(ckpt/notes.txt, policies/deep/b.json\)"):
        check_own_folder(out, KIND, redo=True)

    many = tmp_path / "many"
    many.mkdir()
    for i in range(8):
        (many / f"f{i}.txt").write_text("")
    with pytest.raises(ForeignFiles, match=r"holds f0.txt, f1.txt, f2.txt, f3.txt, f4.txt and 3 more\)"):
        check_own_folder(many, KIND, redo=True)
    with pytest.raises(ForeignFiles, match="exists and is not a folder"):
        check_own_folder(many / "f0.txt", KIND, redo=True)


def test_force_overwrites_only_a_file_with_drivee2e_s_signature(tmp_path):
    f = tmp_path / "a.mcap"
    check_own_file(f, b"drivee2e-jax", "MCAP file")  # missing: fine
    f.write_bytes(b"\x89MCAP0\r\n" + b"\x01" * 13 + b"drivee2e-jax" + b"\0" * 5000)
    check_own_file(f, b"drivee2e-jax", "MCAP file")
    f.write_bytes(b"the user's own recording")
    with pytest.raises(ForeignFiles, match=rf"^{f}: not a MCAP file drivee2e wrote; --force overwrites only"):
        check_own_file(f, b"drivee2e-jax", "MCAP file")
    f.write_bytes(b"\0" * 5000 + b"drivee2e-jax")  # only the head is read
    with pytest.raises(ForeignFiles):
        check_own_file(f, b"drivee2e-jax", "MCAP file")
    with pytest.raises(ForeignFiles, match="is a folder"):
        check_own_file(tmp_path, b"drivee2e-jax", "MCAP file")


@pytest.mark.parametrize("text, key", [
    ('{"ego_track_id": 1, "ego_track_id": 4}', "ego_track_id"),
    ('{"tracks": [{"id": 1, "x": [1, 2], "id": 2}]}', "id"),
    ('[1, 2, {"q": 1, "q": 1}]', "q"),  # behind scalars in a list
    ('{"s": "{:", "a": [1, {"b": 1, "b": 2}]}', "b"),  # braces and colons inside strings
    ('{"a": NaN, "a": 1}', "a"),  # what orjson refuses goes to the standard library
    ('{"a\\u003a": 1, "c": 2, "c": 3}', "c"),  # an escaped colon cannot hide a repeat
])
def test_a_repeated_key_is_an_error_naming_the_key(text, key, tmp_path):
    with pytest.raises(DuplicateKeyError) as e:
        loads_json(text)
    assert e.value.key == key and str(e.value) == f"duplicate key {key!r}" and isinstance(e.value, ValueError)
    f = tmp_path / "scenario.json"
    f.write_text(text)
    with pytest.raises(JSONFileError, match=rf"^{f}: unreadable \(duplicate key '{key}'\)$"):
        read_json(f)


@pytest.mark.parametrize("text", ['{"a": 1, "b": {"a": 2}}', '{"s": "x:y{", "t": ["{", ":"]}', '[]', '3', '"a:b"',
                                  '{"a": [[1, 2], [3, {"a": 1}]], "n": NaN}', '{"a\\u003a": 1}'])
def test_json_without_repeats_reads_as_the_standard_library_does(text):
    import json
    import math

    got, want = loads_json(text), json.loads(text)
    if isinstance(want, dict) and isinstance(want.get("n"), float):
        assert math.isnan(got.pop("n")) and math.isnan(want.pop("n"))
    assert got == want


def test_read_json_errors_are_one_line_naming_the_file(tmp_path):
    f = tmp_path / "bad.json"
    f.write_text('{"a": }')
    with pytest.raises(JSONFileError, match=rf"^{f}: unreadable \(Expecting value: line 1 column 7"):
        read_json(f)
    f.write_bytes(b'{"a": "\xff"}')
    with pytest.raises(JSONFileError, match="not UTF-8 text: byte 7 undecodable"):
        read_json(f)
