"""Results files of a benchmark run (host side).

Layout of ``results/<run>/``::

    run.json                 what was run (suite, split, config) — resume checks it
    policies/<policy>.json   one finished policy: per-scenario records + events
    scenarios.csv            one row per (policy, scenario)
    scenarios.json           the same rows, each with its infraction events
    summary.json             aggregates per policy, per behaviour, per intersection

Every file is written atomically (temp file + ``os.replace``), so an
interrupted run never leaves a partial file; a finished policy file is the
unit of resumption.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Iterable
from pathlib import Path

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import atomic_write_json, atomic_write_text, json_default


#: Columns every per-scenario row has, in CSV order (count columns follow).
def event_key(row: dict) -> str:
    """Key of a row's infraction events in a policy file: the scenario id,
    suffixed ``#<repetition>`` from the second repetition on."""
    rep = row.get("repetition") or 0
    return row["scenario_id"] if not rep else f"{row['scenario_id']}#{rep}"


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
    "eval_time_s",
)


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


class RunDir:
    """A results folder that can be resumed.

    ``RunDir(path, run_info, force)`` refuses a folder holding results of a
    *different* run (other suite/split/config) unless ``force``; with ``force``
    the old policy files are removed first. Otherwise finished policies are
    skipped (``done(policy)``).
    """

    def __init__(self, path: str | Path, run_info: dict, force: bool = False):
        self.path = Path(path)
        self.info = run_info
        meta = self.path / "run.json"
        if self.path.exists() and any(self.path.iterdir()):
            if force:
                for f in (self.path / "policies").glob("*.json"):
                    f.unlink()
            elif meta.exists():
                try:
                    old = json.loads(meta.read_text())
                except json.JSONDecodeError as e:
                    raise DriveE2EError(f"{meta}: unreadable ({e}); use --force to start over") from e
                if old != json.loads(json.dumps(run_info, default=json_default)):
                    diff = sorted(k for k in set(old) | set(run_info) if old.get(k) != run_info.get(k))
                    raise DriveE2EError(
                        f"{self.path}: holds results of a different run (differs in {', '.join(diff)}); "
                        "use --force to overwrite or --out to choose another folder"
                    )
            else:
                raise DriveE2EError(f"{self.path}: exists and is not a drivee2e results folder; use --force or another --out")
        self.path.mkdir(parents=True, exist_ok=True)
        atomic_write_json(meta, run_info)

    def policy_file(self, policy: str) -> Path:
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in policy)
        return self.path / "policies" / f"{safe}.json"

    def done(self, policy: str) -> bool:
        return self.policy_file(policy).exists()

    def save_policy(self, policy: str, rows: list[dict], events: dict[str, list[dict]], extra: dict) -> None:
        atomic_write_json(self.policy_file(policy), {"policy": policy, "rows": rows, "events": events, **extra})

    def load_policy(self, policy: str) -> dict:
        return json.loads(self.policy_file(policy).read_text())

    def write_tables(self, policies: list[str], summary: dict, count_columns: Iterable[str]) -> None:
        """Combine finished policy files into scenarios.csv/.json and summary.json."""
        rows, rows_json = [], []
        for p in policies:
            data = self.load_policy(p)
            for r in data["rows"]:
                rows.append(r)
                rows_json.append({**r, "events": data["events"].get(event_key(r), [])})
        cols = list(BASE_COLUMNS) + [c for c in count_columns if c not in BASE_COLUMNS]
        # Then every other per-scenario column (fine-grained, open-loop ...) in first-seen order.
        for r in rows:
            cols += [k for k in r if k not in cols]
        atomic_write_text(self.path / "scenarios.csv", rows_to_csv(rows, cols))
        atomic_write_json(self.path / "scenarios.json", rows_json)
        atomic_write_json(self.path / "summary.json", summary)
