"""The checkpoint-trend study: open-loop vs closed-loop metrics across a run's checkpoints.

For every checkpoint ``RUN/checkpoints/<epoch>`` of a training run, on one
split: open-loop L2 at 1 s / 2 s and the open-loop collision rate on the
logged demonstrations (``openloop.evaluate_openloop``), and closed-loop SR /
DS (``closedloop.evaluate``, aggregated by ``summary.summary_of``) -- the
source paper's Figure 5, which shows that lower L2 need not mean better
driving. One policy object serves every checkpoint (the parameters are an
argument), so the open-loop program compiles once.

Output folder::

    DIR/checkpoints/<epoch>.json   one row per checkpoint, with the inputs it was made from (resumable:
                                   a row is reused only when its inputs are this run's)
    DIR/trend.csv                  the rows, by epoch
    DIR/trend.png                  open-loop (left) and closed-loop (right) against the epoch
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.eval.openloop import ShortHorizonError, evaluate_openloop
from drivee2e_jax.eval.results import fingerprint_differences, package_version, rows_to_csv
from drivee2e_jax.eval.runspec import batch_sha256
from drivee2e_jax.eval.summary import OPEN_LOOP_COLUMNS, summary_of
from drivee2e_jax.files import (
    ForeignFiles,
    OwnFolder,
    atomic_write,
    atomic_write_json,
    atomic_write_text,
    check_own_folder,
    read_json,
    sha256_tree,
)
from drivee2e_jax.models import checkpoint as ckpt
from drivee2e_jax.models.base import as_policy
from drivee2e_jax.models.checkpoint import training_bev
from drivee2e_jax.observe.sensors import SensorConfig
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.train.loop import model_of_run

#: trend.csv columns, in order. l2_* follow ST-P3 (mean over the steps up to
#: k s), *_uniad the value at k s; rates in [0, 1]; SR in %, DS in [0, 100].
COLUMNS = (
    "checkpoint", "epoch", "step", "env_steps", "train_loss", "l2_1s", "l2_2s", "l2_1s_uniad", "l2_2s_uniad",
    "openloop_collision_rate", "openloop_samples", "success_rate", "driving_score", "route_completion",
    "num_scenarios", "eval_s",
)


#: What a trend folder holds; a folder with any other file is refused.
TREND_FOLDER = OwnFolder("trend", None, ("trend.csv", "trend.png", "checkpoints/*.json"))


def evaluate_checkpoint(policy, params, packed, maps, *, limit: int | None, seed: int) -> dict:
    """Open- and closed-loop metrics of ``policy`` with ``params`` on ``packed``
    (the open-loop ones None when the policy's waypoints end before the
    open-loop horizon, e.g. a two-waypoint PPO actor)."""

    res = evaluate(policy, packed, None, params=params, seed=seed, limit=limit, maps=maps)
    try:
        ol = evaluate_openloop(policy, packed, params=params, seed=seed, limit=limit, maps=maps)
    except ShortHorizonError:
        ol = {r["scenario_id"]: dict.fromkeys(OPEN_LOOP_COLUMNS) for r in res.rows}
    rows = [{**r, **{c: ol[r["scenario_id"]][c] for c in OPEN_LOOP_COLUMNS}} for r in res.rows]
    s = summary_of(rows)
    return {
        "l2_1s": s.get("l2_1s_stp3"), "l2_2s": s.get("l2_2s_stp3"),
        "l2_1s_uniad": s.get("l2_1s_uniad"), "l2_2s_uniad": s.get("l2_2s_uniad"),
        "openloop_collision_rate": s.get("openloop_collision_rate"),
        "openloop_samples": s.get("openloop_samples"),
        "success_rate": s["success_rate"], "driving_score": s["driving_score"],
        "route_completion": s["route_completion"], "num_scenarios": s["num_scenarios"],
    }


def run_trend(run_dir: str | Path, out: str | Path, *, suite: str | None = None, split: str = "val",
              limit: int | None = None, seed: int = 0, mode: str = "traj",
              print_fn: Callable[[str], None] = print) -> list[dict]:
    """Evaluate every checkpoint of ``run_dir``; write ``out``; return the rows.

    Args:
      run_dir: a ``drivee2e train`` run folder.
      out: output folder (rows already there are reused; a folder with
        other files than a trend's, ``TREND_FOLDER``, is refused).
      suite: suite name / folder (default: the one the run's dataset was built from).
      split: split evaluated.  limit: only its first ``limit`` scenarios.
      mode: ``models.base.as_policy`` mode ("traj" for the open-loop metrics).
    """

    run_dir, out = Path(run_dir), Path(out)
    try:  # rows, table and plot overwrite only a trend folder's own files
        check_own_folder(out, TREND_FOLDER, redo=True)
    except ForeignFiles as e:
        raise DriveE2EError(str(e)) from None
    ckpts = ckpt.list_checkpoints(run_dir)
    if not ckpts:
        raise DriveE2EError(f"{run_dir}: no checkpoints (expected {run_dir}/checkpoints/<epoch>; run `drivee2e train`)")
    model = model_of_run(run_dir)
    suite = load_suite(suite or _run_suite(run_dir))
    packed = suite.pack(split)
    maps = suite.maps if getattr(model, "required_sensors", ()) else None
    bev = training_bev(ckpt.read_meta(ckpts[-1]))
    policy = as_policy(model, None, mode, sensor_config=None if bev is None else SensorConfig(bev=bev))
    # What a row depends on: reused only when all of it is unchanged.
    common = {"suite_sha256": batch_sha256(packed if limit is None else packed.select(np.arange(min(limit, len(packed))))),
              "split": split, "limit": limit, "seed": seed, "mode": mode, "drivee2e_version": package_version()}
    rows = []
    for c in ckpts:
        row_file = out / "checkpoints" / f"{c.name}.json"
        inputs = {**common, "checkpoint_sha256": sha256_tree(c)}
        row = read_json(row_file) if row_file.is_file() else None
        stale = None if row is None else _stale(row, inputs)
        if row is not None and not stale:
            print_fn(f"[epoch {c.name}] reused {row_file}")
        else:
            if stale:
                print_fn(f"[epoch {c.name}] evaluated again: {row_file} was made from other inputs ({stale})")
            meta = ckpt.read_meta(c)
            t0 = time.perf_counter()
            got = evaluate_checkpoint(policy, ckpt.load_params(c), packed, maps, limit=limit, seed=seed)
            row = {"checkpoint": str(c), "epoch": int(meta["epoch"]), "step": int(meta.get("step", 0)),
                   "env_steps": meta.get("env_steps"),  # PPO runs: environment steps trained on
                   "train_loss": meta.get("train_loss"), **got, "eval_s": round(time.perf_counter() - t0, 1),
                   "inputs": inputs}
            atomic_write_json(row_file, row)
            print_fn(f"[epoch {row['epoch']}] L2 1s {_fmt(row['l2_1s'])} m, 2s {_fmt(row['l2_2s'])} m, "
                     f"col {_fmt(row['openloop_collision_rate'], 4)}; SR {row['success_rate']:.1f}, "
                     f"DS {row['driving_score']:.2f} ({row['eval_s']:.0f} s)")
        rows.append(row)
    rows.sort(key=lambda r: r["epoch"])
    atomic_write_text(out / "trend.csv", rows_to_csv(rows, COLUMNS))
    plot_trend(rows, out / "trend.png", title=f"{model.name}: {run_dir.name}, {split}")
    return rows


def _stale(row, inputs: dict) -> str:
    """Why a stored checkpoint row cannot be reused ('' when it can): the
    inputs it records (suite batch, split, limit, seed, mode, checkpoint
    files, package version) differ from this run's, or it records none (a
    row from before they were recorded, or not a row)."""
    if not isinstance(row, dict) or not isinstance(row.get("inputs"), dict):
        return "it records no inputs"
    return ", ".join(fingerprint_differences(row["inputs"], inputs)) + (" changed" if row["inputs"] != inputs else "")


def _fmt(v, digits: int = 3) -> str:
    """A metric for printing ("-" when undefined: no open-loop sample)."""
    return "-" if v is None else f"{v:.{digits}f}"


def _run_suite(run_dir: Path) -> str:
    """The suite the run's dataset was recorded from, or a PPO run's suite
    (twin15 if unknown)."""
    try:
        cfg = read_json(run_dir / "config.json")
        if "ppo" in cfg:
            return cfg["ppo"]["suite"]
        data = cfg["data"]
        return read_json(Path(data) / "manifest.json")["suite"]
    except (OSError, ValueError, KeyError):
        return "twin15"


def plot_trend(rows: list[dict], path: Path, title: str = "") -> None:
    """Two panels against the epoch: open-loop L2 1 s / 2 s (+ collision rate,
    right axis) on the left, closed-loop SR / DS on the right."""
    ep = [r["epoch"] for r in rows]
    val = lambda k: [np.nan if r.get(k) is None else r[k] for r in rows]  # noqa: E731
    fig = Figure(figsize=(10, 3.8))
    FigureCanvasAgg(fig)
    a, b = fig.subplots(1, 2)
    a.plot(ep, val("l2_1s"), "o-", label="L2 @ 1 s")
    a.plot(ep, val("l2_2s"), "s-", label="L2 @ 2 s")
    a.set_xlabel("epoch")
    a.set_ylabel("open-loop L2, m (lower is better)")
    a2 = a.twinx()
    a2.plot(ep, [100 * v for v in val("openloop_collision_rate")], "^--", color="tab:red", label="collision %")
    a2.set_ylabel("open-loop collision rate, %")
    h1, l1 = a.get_legend_handles_labels()
    h2, l2 = a2.get_legend_handles_labels()
    a.legend(h1 + h2, l1 + l2, fontsize=8)
    a.set_title("open loop (logged demonstrations)")
    b.plot(ep, val("driving_score"), "o-", color="tab:green", label="DS")
    b.plot(ep, val("success_rate"), "s-", color="tab:purple", label="SR %")
    b.set_xlabel("epoch")
    b.set_ylabel("closed loop (higher is better)")
    b.legend(fontsize=8)
    b.set_title("closed loop")
    for ax in (a, b):
        ax.set_xticks(ep)
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110), binary=True)
