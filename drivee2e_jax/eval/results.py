"""Results folders of benchmark runs (host side): what they hold and the rules
that keep them true.

Layout of ``results/<run>/``::

    run.json                 what was run: the RunSpec (suite, split, config),
                             "fingerprint" and "provenance" (below)
    policies/<policy>.json   one finished policy: rows, events, warnings,
                             "fingerprint", "provenance"; the unit of resumption
    scenarios.csv / .json    one row per (policy, scenario) of EVERY policy file,
                             without wall-clock columns: two identical runs give
                             byte-identical tables (check with ``cmp``)
    timing.json              the wall-clock columns (``TIMING_COLUMNS``) of those
                             rows: {"rows": [{"policy", "scenario_id",
                             "repetition", "eval_time_s"}, ...]}, same order
    summary.json             aggregates per policy (every policy file)
    report.md, plots/, leaderboard/<policy>.json   made from the same files
    .lock                    held by the run writing the folder

The contract (``RunDir``):

* **One writer.** A run holds an exclusive ``fcntl.flock`` on ``.lock``
  (``files.lock_folder``) from before its first check until its tables are
  written; a second run of the same folder stops at once with one line naming
  the holder (pid, host, start time, command). The kernel releases the lock
  of a killed run. Under the lock, temp files a killed run left
  (``files.remove_stray_temp_files``) are deleted.
* **Atomic files.** Every file is written to a temp file and renamed into
  place: a reader sees the old or the new file, never half of one.
* **Tables cover the folder.** The combined tables list every finished
  policy file in the folder, this run's policies first (in its order), then
  the others sorted by name, so a rerun with fewer ``--policy`` flags drops
  nothing.
* **Resume only what is the same.** ``run.json`` records the RunSpec and a
  ``fingerprint``: ``suite_sha256`` (``runspec.batch_sha256``: the packed
  arrays actually evaluated, so an edited scenario file, a regenerated suite
  or a different limit/variant all change it, while moving or touching the
  suite folder does not) and ``drivee2e_version``. Any difference: the run is
  refused with one line (``--force`` or another ``--out``); so a folder
  scored with another ``--preset``, ``--collisions`` or ``--agents`` (all in
  the RunSpec) is never mixed into the combined tables. A run.json
  without fingerprints (written by an older version) is refused too. Each
  policy file records its policy's ``fingerprint`` (``policy_fingerprint``:
  sha256 of the policy file, the ``make_policy`` arguments, sha256 of a
  checkpoint file or folder an argument names); a policy is skipped only
  when it matches, and a mismatch stops the run with one line naming the
  policy and what changed (refusing is the safe default: ``--force``, or
  delete that one file). The policy fingerprint covers the modules the
  policy file imports from its own folder too (``modules_sha256``). Remote policies (``remote://``) are never resumed:
  the server can serve another policy behind the same address. A corrupt
  policy file stops the run with one line naming it.
* **Readers check the same fingerprints.** ``view`` / ``export-mcap``
  (``eval.traces.check_current``) recompute the suite and policy
  fingerprints and refuse a stale folder (``check_run_current``,
  ``check_policy_current``) in one line saying what changed.
* **``--force`` never deletes what drivee2e did not write.** A non-empty
  folder without run.json is refused with or without ``--force``; under
  ``--force`` so is a results folder holding any file outside
  ``RESULTS_FOLDER`` (``files.check_own_folder``), naming the files.
* **Nothing before validation.** ``eval.bench`` writes nothing to the folder
  before every input is checked and every policy loaded; a run that fails
  before any policy finished removes what it created.
* **Provenance** (``run.json`` ``provenance``, not compared on resume;
  rewritten by every run): package version, git commit and dirty flag when
  the package is a git checkout, JAX / jaxlib versions, backend and device
  kinds, UTC time, command line, the suite as recorded. Each policy file's
  ``provenance``: the policy as recorded (a zoo policy by name, a path inside
  the folder relative to it, else as given), its sha256, the files its
  arguments name, UTC time written.
"""

from __future__ import annotations

import contextlib
import csv
import datetime
import importlib.metadata
import io
import json
import shlex
import shutil
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.runspec import RUN_JSON
from drivee2e_jax.files import (
    LOCK_NAME,
    FolderLocked,
    ForeignFiles,
    OwnFolder,
    atomic_write_json,
    atomic_write_text,
    check_own_folder,
    is_stray_temp_file,
    json_default,
    lock_folder,
    remove_stray_temp_files,
    sha256_file,
    sha256_tree,
)
from drivee2e_jax.jsonfile import BadJSON, read_json
from drivee2e_jax.policy import local_modules, reference_policy_dir, zoo_weight_files
from drivee2e_jax.remote import is_remote_spec


def event_key(row: dict) -> str:
    """Key of a row's infraction events in a policy file: the scenario id,
    suffixed ``#<repetition>`` from the second repetition on."""
    rep = row.get("repetition") or 0
    return row["scenario_id"] if not rep else f"{row['scenario_id']}#{rep}"


#: Columns every per-scenario row has, in CSV order (count columns follow).
BASE_COLUMNS = (
    "policy",
    "scenario_id",
    "split",
    "intersection_id",
    "behavior",
    "weather",
    "time_of_day",
    "route_length_m",
    "route_completion",
    "infraction_score",
    "driving_score",
    "success",
    "status",
    "episode_s",
)

#: Wall-clock columns of a result row: kept in policy files and ``timing.json``,
#: left out of scenarios.csv/.json so that those are deterministic.
TIMING_COLUMNS = ("eval_time_s",)
TIMING_FILE = "timing.json"


def rows_to_csv(rows: list[dict], columns: Iterable[str]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: _csv_value(v) for k, v in r.items()})
    return buf.getvalue()


def _csv_value(v):
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, bool):
        return int(v)
    return v


#: Files the combined tables consist of (rewritten after every run; removed by ``--force``).
TABLE_FILES = ("scenarios.csv", "scenarios.json", "timing.json", "summary.json", "report.md")
#: The figures ``eval.plots.write_plots`` draws into ``plots/``.
PLOT_FILES = ("sr_by_behavior.png", "ds_by_behavior.png", "infractions_per_km.png", "comfort.png")
#: Folders of per-policy outputs derived from the policy files (removed by ``--force``).
TABLE_FOLDERS = (("leaderboard", "*.json"), *(("plots", name) for name in PLOT_FILES))
#: What a results folder holds: ``--force`` redoes only a folder with run.json
#: and no other files than these (``files.check_own_folder``).
RESULTS_FOLDER = OwnFolder("results", RUN_JSON, (RUN_JSON, "policies/*.json", *TABLE_FILES,
                                                 *(f"{sub}/{pattern}" for sub, pattern in TABLE_FOLDERS)))
#: run.json keys not compared on resume.
UNCOMPARED = ("provenance",)
#: What each run.json fingerprint key covers, for "what changed" messages.
RUN_FINGERPRINT_KEYS = {
    "suite_sha256": "the suite's scenarios (a scenario, map or suite.json file edited, or the suite regenerated)",
    "suite_files_sha256": "the suite folder's files (suite.json, a map or a scenario file)",
    "drivee2e_version": "the drivee2e version",
}
#: What each policy fingerprint key means, for "what changed" messages.
POLICY_FINGERPRINT_KEYS = {
    "sha256": "the policy file's content",
    "kwargs": "its make_policy arguments",
    "files_sha256": "the files its arguments name (checkpoint)",
    "modules_sha256": "the modules it imports from its folder",
    "remote": "the remote spec",
}


class RunDir:
    """A results folder owned by this run, resumable and checked (see the
    module docstring for the contract).

    ``RunDir(path, run_info, force, policies=..., provenance=...)``:

    * takes ``lock_folder(path)`` (held until ``close``; DriveE2EError naming
      the holder when another run has it) and removes stray temp files;
    * refuses (DriveE2EError, one line) a folder that is not a results
      folder (not empty, no run.json: checked before the lock, so it gets no
      lock file), a folder of a different run (a ``run_info`` key or
      fingerprint differs), written by an older version (no ``fingerprint``
      in run.json), with a corrupt policy file, or holding a policy of
      ``policies`` whose stored fingerprint differs; ``force`` removes the
      old policy files and tables instead, and only from a folder holding
      nothing but ``RESULTS_FOLDER``'s files (else it is refused naming them);
    * then writes ``run.json`` = ``run_info`` + ``{"provenance": ...}``.

    Args:
      run_info: the compared part of run.json (``RunSpec.to_json()`` plus a
        ``fingerprint`` dict: suite content hash, package version).
      policies: this run's policies: name -> fingerprint (None = never
        resumed: a remote policy), in run order.
      provenance: stored in run.json, not compared.

    ``done(name)``: the policy's file exists and its fingerprint matches.
    ``close()`` releases the lock; when no policy file exists by then, what
    this run created (the folder, or run.json + the lock file in a folder that
    was empty) is removed.
    """

    def __init__(self, path: str | Path, run_info: dict, force: bool = False, *,
                 policies: dict[str, dict | None] | None = None, provenance: dict | None = None):
        self.path = Path(path)
        self.info = _plain(run_info)
        self.policies = dict(policies or {})
        self._created = not self.path.exists()
        self._stack = None
        self._check_own(force)  # before the lock: a folder refused gets no lock file
        self._stack = contextlib.ExitStack()
        try:
            self._stack.enter_context(lock_folder(self.path, hint="wait for it to finish or use another --out"))
        except FolderLocked as e:
            raise DriveE2EError(str(e)) from None
        self._fresh = not self._contents()
        try:
            self._check_own(force)  # again, under the lock
            remove_stray_temp_files(self.path)
            if force:
                self._clear()
            else:
                self._check_run()
            self.files = self._read_policy_files()
            self._resumable = {n for n, fp in self.policies.items() if self._check_policy(n, fp)}
            atomic_write_json(self.path / RUN_JSON, {**self.info, "provenance": provenance or {}})
        except BaseException:
            self.close()
            raise

    # -- lifetime ----------------------------------------------------------------
    def close(self) -> None:
        """Release the lock; remove what this run created if no policy finished."""
        if self._stack is None:
            return
        try:
            if not any(self.policy_dir.glob("*.json")):
                self._remove_own_traces()
        finally:
            self._stack.close()
            self._stack = None

    def __enter__(self) -> RunDir:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _contents(self) -> list[Path]:
        """Entries of the folder other than the lock file and stray temp files."""
        if not self.path.is_dir():
            return []
        return [p for p in self.path.iterdir() if p.name != LOCK_NAME and not is_stray_temp_file(p)]

    def _remove_own_traces(self) -> None:
        if not self._fresh:
            return
        left = {p.name for p in self._contents()}
        if not left <= {RUN_JSON, "policies"} or any(self.policy_dir.iterdir() if self.policy_dir.is_dir() else ()):
            return  # something else appeared: keep it
        if self.policy_dir.is_dir():
            self.policy_dir.rmdir()
        (self.path / RUN_JSON).unlink(missing_ok=True)
        (self.path / LOCK_NAME).unlink(missing_ok=True)
        if self._created:
            shutil.rmtree(self.path, ignore_errors=True)

    # -- checks ------------------------------------------------------------------
    def _check_own(self, force: bool) -> None:
        """DriveE2EError (one line naming the files) for a folder that is not
        drivee2e's: not empty and without run.json, or, with ``force``,
        holding a file a results folder does not have (``RESULTS_FOLDER``)."""
        try:
            check_own_folder(self.path, RESULTS_FOLDER, redo=force)
        except ForeignFiles as e:
            raise DriveE2EError(str(e)) from None

    def _clear(self) -> None:
        """``--force``: remove the old policy files and the tables made from them."""
        for f in self.policy_dir.glob("*.json"):
            f.unlink()
        for name in TABLE_FILES:
            (self.path / name).unlink(missing_ok=True)
        for sub, pattern in TABLE_FOLDERS:
            for f in (self.path / sub).glob(pattern):
                f.unlink()

    def _check_run(self) -> None:
        meta = self.path / RUN_JSON
        if not meta.exists():  # an empty folder (``_check_own`` refused any other)
            return
        try:
            old = read_json(meta)
        except BadJSON as e:
            raise DriveE2EError(f"{e}; use --force to start over") from e
        if not isinstance(old, dict):
            raise DriveE2EError(f"{meta}: not a JSON object; use --force to start over")
        old = {k: v for k, v in old.items() if k not in UNCOMPARED}
        if "fingerprint" not in old:
            raise DriveE2EError(f"{self.path}: written by an older drivee2e version (run.json has no fingerprints, so "
                                "its results cannot be checked against this run); use --force to start over or "
                                "another --out")
        diff = run_differences(old, self.info)
        if diff:
            raise DriveE2EError(f"{self.path}: holds results of a different run (differs in {', '.join(diff)}); "
                                "use --force to overwrite or --out to choose another folder")

    def _read_policy_files(self) -> dict[str, tuple[Path, dict]]:
        """Every policy file: its policy name -> (path, content); corrupt ones raise."""
        out = {}
        for f in sorted(self.policy_dir.glob("*.json")):
            data = read_policy_file(f)
            out[str(data["policy"])] = (f, data)
        return out

    def _check_policy(self, name: str, fingerprint: dict | None) -> bool:
        """True when ``name``'s results can be resumed; DriveE2EError when its file
        was written for a different policy."""
        theirs = {str(p) for p, (f, _) in self.files.items() if f.name == self.policy_file(name).name} - {name}
        if theirs:
            raise DriveE2EError(f"[{name}] its result file {self.policy_file(name)} already holds policy "
                                f"{sorted(theirs)[0]!r} (both names map to one file); rename one policy (name=...)")
        if name not in self.files or fingerprint is None:
            return False
        f, data = self.files[name]
        changed = policy_differences(data.get("fingerprint"), _plain(fingerprint))
        if changed:
            raise DriveE2EError(f"[{name}] {f} was written for a different policy (changed: {changed}); use --force "
                                f"to re-run everything, or delete {f} to re-run only {name}")
        return True

    # -- policy files --------------------------------------------------------------
    @property
    def policy_dir(self) -> Path:
        return self.path / "policies"

    def policy_file(self, policy: str) -> Path:
        return self.policy_dir / f"{policy_file_stem(policy)}.json"

    def done(self, policy: str) -> bool:
        """The policy's results are in the folder and were made by the same policy."""
        return policy in self._resumable

    def save_policy(self, policy: str, rows: list[dict], events: dict[str, list[dict]], extra: dict) -> None:
        """Write ``policies/<policy>.json`` (with its fingerprint from ``policies``)."""
        data = {"policy": policy, "rows": rows, "events": events, **extra}
        if self.policies.get(policy) is not None:
            data["fingerprint"] = self.policies[policy]
        path = self.policy_file(policy)
        atomic_write_json(path, data)
        self.files[policy] = (path, _plain(data))

    def load_policy(self, policy: str) -> dict:
        return self.files[policy][1] if policy in self.files else read_policy_file(self.policy_file(policy))

    def finished(self, first: Iterable[str] = ()) -> list[str]:
        """Every policy with a file in the folder: those of ``first`` (this run's
        order) first, then the others sorted by name."""
        first = [p for p in first if p in self.files]
        return first + sorted(p for p in self.files if p not in first)

    def write_tables(self, policies: list[str], summary: dict, count_columns: Iterable[str]) -> None:
        """Combine finished policy files into scenarios.csv/.json and summary.json."""
        rows, rows_json, timing = [], [], []
        for p in policies:
            data = self.load_policy(p)
            for full in data["rows"]:
                r = {k: v for k, v in full.items() if k not in TIMING_COLUMNS}
                rows.append(r)
                rows_json.append({**r, "events": data["events"].get(event_key(r), [])})
                timing.append({"policy": r.get("policy"), "scenario_id": r.get("scenario_id"),
                               "repetition": r.get("repetition") or 0,
                               **{k: full[k] for k in TIMING_COLUMNS if k in full}})
        cols = list(BASE_COLUMNS) + [c for c in count_columns if c not in BASE_COLUMNS]
        # Then every other per-scenario column (fine-grained, open-loop ...) in first-seen order.
        for r in rows:
            cols += [k for k in r if k not in cols]
        atomic_write_text(self.path / "scenarios.csv", rows_to_csv(rows, cols))
        atomic_write_json(self.path / "scenarios.json", rows_json)
        atomic_write_json(self.path / TIMING_FILE, {"rows": timing})
        atomic_write_json(self.path / "summary.json", summary)


def _plain(obj):
    """``obj`` as JSON would read it back (tuples -> lists, numpy -> Python)."""
    return json.loads(json.dumps(obj, default=json_default))


def policy_file_stem(policy: str) -> str:
    """The file name (without ``.json``) of ``policy``'s results: characters other
    than letters, digits, ``-_.`` become ``_``, so two names can share a file
    (``x/y`` and ``x_y``); ``check_policy_file_names`` refuses that in a run."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in policy)


def check_policy_file_names(names: Iterable[str]) -> None:
    """DriveE2EError (one line) when two policy names map to one result file."""
    seen: dict[str, str] = {}
    for n in names:
        stem = policy_file_stem(n)
        if stem in seen and seen[stem] != n:
            raise DriveE2EError(f"policy names {seen[stem]!r} and {n!r} map to the same result file "
                                f"policies/{policy_file_stem(n)}.json; rename one (name=...)")
        seen[stem] = n


def read_policy_file(path: Path) -> dict:
    """A ``policies/<name>.json``; DriveE2EError (one line) when it is corrupt."""
    try:
        data = read_json(path)
    except BadJSON as e:
        raise DriveE2EError(f"{path} is corrupt ({e.detail}); delete it or use --force") from None
    if not isinstance(data, dict) or not {"policy", "rows", "events"} <= set(data):
        raise DriveE2EError(f"{path} is corrupt (not a policy results object with policy, rows and events); "
                            "delete it or use --force")
    return data


def run_differences(old: dict, new: dict) -> list[str]:
    """The run.json keys (``fingerprint.<key>`` inside the fingerprint) whose
    values differ between two runs (``provenance`` ignored)."""
    new = _plain(new)
    out = []
    for k in sorted((set(old) | set(new)) - set(UNCOMPARED)):
        a, b = old.get(k), new.get(k)
        if k == "fingerprint" and isinstance(a, dict) and isinstance(b, dict):
            out += [f"fingerprint.{s}" for s in fingerprint_differences(a, b)]
        elif a != b:
            out.append(k)
    return out


def run_fingerprint(**suite: str) -> dict:
    """run.json's ``fingerprint``: the suite's (``suite_sha256`` =
    ``runspec.batch_sha256`` of the evaluated batch, or for a run streamed
    from a suite folder ``suite_files_sha256`` = ``runspec.folder_fingerprint``)
    and ``drivee2e_version``. Bench writes it; a resume and every reader of
    the folder (``check_run_current``) compare it."""
    return {**suite, "drivee2e_version": package_version()}


def fingerprint_differences(old: dict, new: dict) -> list[str]:
    """The fingerprint keys whose values differ (sorted)."""
    return [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]


def check_run_current(folder: str | Path, info: dict, fingerprint: dict) -> None:
    """A reader's side of the resume rule (``view``, ``export-mcap``):
    DriveE2EError (one line saying what changed) when ``fingerprint``, the
    run's inputs as they are now (``run_fingerprint``; only the suite keys
    run.json has need computing), differs from run.json's ``info``: results
    of an edited suite or another drivee2e version would be re-simulated as if
    they were the bench's. A run.json without fingerprints is refused too."""
    stored = info.get("fingerprint") if isinstance(info, dict) else None
    if not isinstance(stored, dict):
        raise DriveE2EError(f"{folder}: written by an older drivee2e version (run.json has no fingerprints), so "
                            "whether its suite is unchanged cannot be checked; re-run `drivee2e bench --force` on it")
    diff = fingerprint_differences(stored, _plain(fingerprint))
    if diff:
        what = "; ".join(RUN_FINGERPRINT_KEYS.get(k, k) for k in diff)
        raise DriveE2EError(f"{folder}: stale results: {what} changed since `drivee2e bench` wrote them (differs in "
                            f"{', '.join(f'fingerprint.{k}' for k in diff)}); re-run the bench (--force) first")


def check_policy_current(folder: str | Path, name: str, data: dict, fingerprint: dict) -> None:
    """``check_run_current`` for one policy file: DriveE2EError (one line
    naming the policy and what changed: the policy file, a module it imports,
    its arguments, a checkpoint) when ``fingerprint`` (``policy_fingerprint``
    now) differs from the file's stored one, or it has none."""
    changed = policy_differences(data.get("fingerprint"), _plain(fingerprint))
    if changed:
        raise DriveE2EError(f"[{name}] {folder}: stale results: the policy changed since `drivee2e bench` wrote them "
                            f"(changed: {changed}); re-run the bench (--force) first")


def policy_differences(old: dict | None, new: dict) -> str:
    """What differs between a stored and a new policy fingerprint, in words
    ("" when equal)."""
    if not isinstance(old, dict):
        return "unknown, the file has no fingerprint"
    keys = [k for k in POLICY_FINGERPRINT_KEYS if old.get(k) != new.get(k)]
    keys += sorted(k for k in set(old) | set(new) if k not in POLICY_FINGERPRINT_KEYS and old.get(k) != new.get(k))
    words = []
    for k in keys:
        a, b = old.get(k), new.get(k)
        if k == "modules_sha256":  # name the modules: edited, added or gone
            a, b = a if isinstance(a, dict) else {}, b if isinstance(b, dict) else {}
            names = sorted(m for m in set(a) | set(b) if a.get(m) != b.get(m))
            words.append(f"{POLICY_FINGERPRINT_KEYS[k]} ({', '.join(names)})")
        else:
            words.append(POLICY_FINGERPRINT_KEYS.get(k, k))
    return ", ".join(words)


# -- fingerprints and provenance ---------------------------------------------------
def stored_path(path: str | Path, folder: str | Path) -> str:
    """How a path is recorded in a results folder: a zoo policy by its name
    (``expert``), a path inside ``folder`` relative to it (the folder can be
    moved), anything else as given."""
    p = Path(path)
    try:
        if p.suffix == ".py" and p.resolve().parent == reference_policy_dir():
            return p.stem
        return p.resolve().relative_to(Path(folder).resolve()).as_posix()
    except (ValueError, OSError):
        return str(path)


def policy_fingerprint(path: str | Path, kwargs: dict, *, remote_name: str = "") -> dict:
    """What decides a policy's results, for resuming.

    A file policy: ``sha256`` of the file, its ``make_policy`` ``kwargs`` and,
    for every keyword whose value names an existing file or folder (a
    checkpoint), ``files_sha256[key]`` = ``files.sha256_tree`` of it; for a
    zoo policy without a checkpoint, ``bundled_sha256`` of the weights it
    loads (``policy.zoo_weight_files``). When the file imports modules of
    its own folder (``policy.local_modules``: found statically, recursively),
    ``modules_sha256`` = {their path relative to that folder: sha256}, so
    editing a helper module refuses a resume as editing the policy file does
    (the key is left out when there are none, so older fingerprints still
    match). Modules outside the folder (site-packages) are not hashed; a
    change in drivee2e itself is caught by the run's package version. A remote policy
    (``remote://``): the spec and the server's reported name; it is never
    resumed (the server can change behind the same address)."""
    if is_remote_spec(path):
        return {"remote": str(path), "server_name": remote_name}
    files = {k: sha256_tree(v) for k, v in sorted(kwargs.items()) if isinstance(v, str) and v and Path(v).exists()}
    out = {"sha256": sha256_file(path), "kwargs": dict(kwargs), "files_sha256": files}
    root = Path(path).resolve().parent
    modules = {m.relative_to(root).as_posix(): sha256_file(m) for m in local_modules(path)}
    if modules:
        out["modules_sha256"] = modules
    if "checkpoint" not in kwargs:
        bundled = {f.name: sha256_file(f) for f in zoo_weight_files(path)}
        if bundled:  # the zoo's shipped weights decide its learned policies' results
            out["bundled_sha256"] = bundled
    return _plain(out)


def policy_provenance(path: str | Path, kwargs: dict, fingerprint: dict, folder: str | Path) -> dict:
    """The ``provenance`` of a policy file: the policy as recorded
    (``stored_path``), the sha256 of its file and of the files its arguments
    name (by the recorded path), and when it was written (UTC)."""
    out = {"policy": str(path) if is_remote_spec(path) else stored_path(path, folder), "time_utc": utc_now()}
    if "sha256" in fingerprint:
        out["policy_sha256"] = fingerprint["sha256"]
    if fingerprint.get("modules_sha256"):
        out["modules_sha256"] = fingerprint["modules_sha256"]
    files = fingerprint.get("files_sha256") or {}
    if files:
        out["files"] = {k: {"path": stored_path(kwargs[k], folder), "sha256": v} for k, v in files.items()}
    return out


def utc_now() -> str:
    """Now, UTC, ISO 8601 to the second."""
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def package_version() -> str:
    """drivee2e-jax's installed version ("unknown" when not installed)."""
    try:
        return importlib.metadata.version("drivee2e-jax")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def git_state(package_dir: Path | None = None) -> dict:
    """``{"git_commit", "git_dirty"}`` when the package is a git checkout (the
    repository root holds the package folder), else {} (silent: no git, not a
    checkout, an installed copy inside some other repository)."""
    pkg = (package_dir or Path(__file__).resolve().parents[1]).resolve()
    try:
        top = _git(pkg, "rev-parse", "--show-toplevel").strip()
        if not top or Path(top).resolve() != pkg.parent:
            return {}
        commit = _git(pkg, "rev-parse", "HEAD").strip()
        dirty = bool(_git(pkg, "status", "--porcelain", "--untracked-files=no").strip())
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"git_commit": commit, "git_dirty": dirty}


def _git(cwd: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(cwd), *args], capture_output=True, text=True, timeout=10,
                          check=True).stdout


def run_provenance(folder: str | Path, suite: str, extra: dict | None = None) -> dict:
    """run.json's ``provenance`` (not compared on resume): package version, git
    commit (when a checkout), UTC time, command line, the suite as recorded
    (``stored_path`` for a folder), plus ``extra`` (JAX versions, devices)."""
    suite_rec = stored_path(suite, folder) if Path(suite).exists() else suite
    return {"drivee2e_version": package_version(), **git_state(), "time_utc": utc_now(),
            "command": shlex.join(sys.argv), "suite": suite_rec, **(extra or {})}
