"""`drivee2e export-mcap`: --force overwrites only an MCAP file drivee2e wrote."""

from __future__ import annotations

from drivee2e_jax.cli import main
from drivee2e_jax.io.mcap_export import LIBRARY


def test_force_overwrites_only_an_mcap_file_drivee2e_wrote(tmp_path, capsys):
    results = tmp_path / "results"
    results.mkdir()
    out = tmp_path / "a.mcap"
    out.write_bytes(b"\x89MCAP0\r\n" + b"\x01" + b"\0" * 12 + b"other-tool" + b"\0" * 100)
    assert main(["export-mcap", str(results), "--out", str(out), "--force"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0] == (f"drivee2e: error: {out}: not a MCAP file drivee2e wrote; --force overwrites "
                                        "only drivee2e's own files: move it away or choose another --out")
    out.write_bytes(b"\x89MCAP0\r\n" + b"\x01" + b"\0" * 12 + LIBRARY.encode() + b"\0" * 100)
    assert main(["export-mcap", str(results), "--out", str(out), "--force"]) == 2  # accepted: fails later, reading
    err = capsys.readouterr().err
    assert "not a drivee2e results folder" in err and out.exists()
