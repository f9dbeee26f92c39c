"""The baselines study (source paper, Tables 4 and 5): train, evaluate, tabulate.

    python experiments/baselines/run.py --out results/baselines [--runs runs/baselines] \
        [--models ad_mlp,tcp,vector_transformer] [--epochs ad_mlp=20,tcp=8,vector_transformer=16] [--split val]

1. Trains each model on the twin15 train demonstrations with
   ``drivee2e train --model M --data D --epochs N --out RUNS/M`` (vector
   demonstrations ``data/demos-train`` for ad_mlp / vector_transformer, the
   BEV ones ``data/demos-train-bev`` for tcp). A run that already has all N
   epochs is skipped, an interrupted one continues with ``--resume``.
2. Evaluates, in one ``drivee2e bench --open-loop`` results folder
   (``OUT/bench-<split>``), every trained policy (tcp in its three modes:
   fused, tcp_traj, tcp_ctrl) and the references stop, constant_velocity
   (and ``--references`` more, e.g. log_replay,expert). bench skips policies
   it already finished, so an interrupted evaluation resumes.
3. Writes ``OUT/table4.csv|md`` (one row per policy: L2 1 s / 2 s / avg,
   open-loop collision rate, SR, DS, RC, IS, collisions/km, evaluation time
   per scene with and without compilation, training epochs and minutes) and ``OUT/per_behaviour.csv|md``
   (SR and DS per behaviour group x policy), atomically, plus
   ``OUT/provenance.json`` (commands, training times) and
   ``OUT/evaluations.jsonl`` (one line per bench invocation: when, which
   policies, the waypoint controller's state).

Aggregates come from the bench's per-scenario rows through
``drivee2e_jax.eval.summary.summary_of`` (the same numbers ``drivee2e bench``
prints). L2 avg is the mean of L2 @ 1 s and @ 2 s, as the source's Table 4
(e.g. AD-MLP: (4.98 + 11.75) / 2 = 8.36); L2 is in the ST-P3 convention
(mean over the steps up to t). Training minutes are the training-loop time
from ``RUNS/M/log.jsonl`` (summed over resumed segments; imports, data
loading and process start-up excluded).

Bad input (unknown model, missing demonstrations folder, malformed
``--epochs``) prints one line ``baselines: error: ...`` and exits 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))  # `python experiments/baselines/run.py` without an install

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.results import rows_to_csv
from drivee2e_jax.eval.summary import BEHAVIOR_ORDER as BEHAVIOURS  # the source's Table 5 order
from drivee2e_jax.files import atomic_write_json, atomic_write_text
from drivee2e_jax.policy import REFERENCE_POLICIES as KNOWN_REFERENCES  # names `drivee2e bench` accepts

#: model -> (demonstrations folder, default epochs, evaluated policies as (result name, policy file)).
MODELS = {
    "ad_mlp": ("data/demos-train", 20, (("ad_mlp", "ad_mlp"),)),
    "tcp": ("data/demos-train-bev", 8, (("tcp", "tcp"), ("tcp_traj", "tcp_traj"),
                                         ("tcp_ctrl", "tcp_ctrl"))),
    "vector_transformer": ("data/demos-train", 16, (("vector_transformer", "vector_transformer"),)),
}
#: Reference policies always evaluated (lower bound and the simplest mover).
REFERENCES = ("stop", "constant_velocity")

#: Table 4 columns: (csv key, markdown header, decimals).
TABLE4_COLUMNS = (
    ("policy", "policy", None),
    ("model", "model", None),
    ("train_epochs", "epochs", 0),
    ("train_min", "train min", 1),
    ("l2_1s", "L2 1 s", 3),
    ("l2_2s", "L2 2 s", 3),
    ("l2_avg", "L2 avg", 3),
    ("openloop_collision_pct", "OL coll. %", 2),
    ("success_rate", "SR %", 1),
    ("driving_score", "DS", 2),
    ("route_completion", "RC", 2),
    ("infraction_score", "IS", 3),
    ("collisions_per_km", "coll./km", 2),
    ("eval_s_per_scene", "eval s/scene", 3),
    ("rollout_s_per_scene", "rollout s/scene", 3),
)
#: Extra CSV-only columns.
TABLE4_EXTRA = ("l2_3s", "l2_1s_uniad", "l2_2s_uniad", "num_scenarios", "openloop_samples", "compile_s", "rollout_s")


# ----------------------------------------------------------------------------- arguments


@dataclasses.dataclass(frozen=True)
class StudyConfig:
    """One baselines study.

    Attributes:
      out: tables folder.  runs: training runs folder (RUNS/<model>).
      models: models to train and evaluate (keys of ``MODELS``).
      epochs: per model, training epochs.  split: evaluation split.
      suite: suite name or folder.  references: reference policies.
      limit: only the first N scenarios of the split (smoke runs).
      train_only / eval_only: skip the other phase.
    """

    out: Path
    runs: Path
    models: tuple[str, ...]
    epochs: dict
    split: str = "val"
    suite: str = "twin15"
    references: tuple[str, ...] = REFERENCES
    limit: int | None = None
    train_only: bool = False
    eval_only: bool = False
    data: dict = dataclasses.field(default_factory=dict)  # model -> demonstrations folder override


def parse_models(text: str) -> tuple[str, ...]:
    """``"ad_mlp,tcp"`` -> ("ad_mlp", "tcp"); unknown names are an error."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise DriveE2EError("--models: expected a comma-separated list of models, got nothing")
    for n in names:
        if n not in MODELS:
            raise DriveE2EError(f"--models: unknown model {n!r} (expected one of {', '.join(MODELS)})")
    return names


def parse_epochs(text: str, models: tuple[str, ...]) -> dict:
    """``"ad_mlp=20,tcp=16"`` -> epochs per model (defaults for the others)."""
    epochs = {m: MODELS[m][1] for m in models}
    for item in filter(None, (s.strip() for s in (text or "").split(","))):
        key, eq, value = item.partition("=")
        if not eq or key not in MODELS:
            raise DriveE2EError(f"--epochs: expected MODEL=N with MODEL one of {', '.join(MODELS)}, got {item!r}")
        try:
            n = int(value)
        except ValueError:
            n = 0
        if n < 1:
            raise DriveE2EError(f"--epochs: {key}: expected a positive integer, got {value!r}")
        if key in epochs:
            epochs[key] = n
    return epochs


def parse_references(text: str) -> tuple[str, ...]:
    names = tuple(dict.fromkeys([*REFERENCES, *(n.strip() for n in (text or "").split(",") if n.strip())]))
    for n in names:
        if n not in KNOWN_REFERENCES:
            raise DriveE2EError(f"--references: unknown reference policy {n!r} (expected one of {', '.join(KNOWN_REFERENCES)})")
    return names


def rel(path: Path | str) -> str:
    """``path`` relative to the working directory when it is below it (shorter commands)."""
    path = Path(path)
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def data_folder(cfg: StudyConfig, model: str) -> Path:
    """The model's demonstrations: ``--data`` (relative to the working
    directory), else the default folder of the repository."""
    return Path(cfg.data[model]) if model in cfg.data else Path(rel(REPO / MODELS[model][0]))


def check_inputs(cfg: StudyConfig) -> None:
    """Fail early, in one line, on demonstrations that are not there (for
    the models that still need training)."""
    if cfg.eval_only:
        return
    for m in cfg.models:
        if train_state(cfg.runs / m, cfg.epochs[m]) == "done":
            continue
        d = data_folder(cfg, m)
        if not (d / "manifest.json").is_file():
            raise DriveE2EError(f"{d}: demonstrations for {m} not found (expected a folder with manifest.json; "
                                f"build it with `drivee2e dataset build --suite twin15 --split train --out {d}"
                                f"{' --sensors bev' if m == 'tcp' else ''}`)")


# ----------------------------------------------------------------------------- training


def epochs_done(run_dir: Path) -> int:
    """Epochs a training run has checkpointed (0 when there is no run)."""
    ck = run_dir / "checkpoints"
    if not ck.is_dir():
        return 0
    return max((int(p.name) for p in ck.iterdir() if p.name.isdigit()), default=0)


def train_state(run_dir: Path, epochs: int) -> str:
    """``"done"``, ``"resume"`` or ``"new"`` for a run that should have ``epochs``."""
    cfg_file = run_dir / "config.json"
    if not cfg_file.is_file():
        return "new"
    planned = json.loads(cfg_file.read_text()).get("epochs")
    if planned != epochs:
        raise DriveE2EError(f"{run_dir}: a run of {planned} epochs exists, {epochs} requested "
                            "(use --epochs to match it, or another --runs folder)")
    return "done" if epochs_done(run_dir) >= epochs else "resume"


def train_time_s(log_path: Path) -> float:
    """Training-loop seconds of a run from its ``log.jsonl``: the time of the
    last epoch event of each process (``time`` restarts at 0 when a run is
    resumed), summed."""
    if not log_path.is_file():
        return float("nan")
    total, last, prev = 0.0, 0.0, -1.0
    for line in log_path.read_text().splitlines():
        if not line.strip():
            continue
        rec = json.loads(line)
        t = float(rec.get("time", 0.0))
        if t < prev:  # a new process (resume): bank the previous segment
            total, last = total + last, 0.0
        prev = t
        if rec.get("event") == "epoch":
            last = t
    return total + last


def train_command(cfg: StudyConfig, model: str, resume: bool) -> list[str]:
    cmd = ["drivee2e", "train", "--model", model, "--data", str(data_folder(cfg, model)),
           "--epochs", str(cfg.epochs[model]), "--out", str(cfg.runs / model), "--no-progress"]
    return cmd + (["--resume"] if resume else [])


def train_all(cfg: StudyConfig, log) -> dict:
    """Train every model that is not finished; returns per model its
    epochs, training-loop seconds and command (+ wall seconds when run now)."""
    out = {}
    for m in cfg.models:
        run_dir = cfg.runs / m
        state = train_state(run_dir, cfg.epochs[m])
        cmd = train_command(cfg, m, resume=state == "resume")
        info = {"epochs": cfg.epochs[m], "command": " ".join(train_command(cfg, m, False)), "data": str(data_folder(cfg, m))}
        if state == "done":
            log(f"[train {m}] {run_dir}: all {cfg.epochs[m]} epochs present, skipped")
        else:
            log(f"[train {m}] {' '.join(cmd)}")
            wall = _run(cmd, cfg.out / "logs" / f"train-{m}.log")
            info["last_command_wall_s"] = round(wall, 1)
        info["train_loop_s"] = round(train_time_s(run_dir / "log.jsonl"), 1)
        out[m] = info
    return out


# ----------------------------------------------------------------------------- evaluation


def policy_specs(cfg: StudyConfig) -> list[tuple[str, str]]:
    """(result name, ``drivee2e bench --policy`` argument) of every evaluated policy."""
    specs = []
    for m in cfg.models:
        for name, path in MODELS[m][2]:
            specs.append((name, f"{rel(REPO / path)}:checkpoint={cfg.runs / m},name={name}"))
    return specs + [(r, r) for r in cfg.references]


def bench_dir(cfg: StudyConfig) -> Path:
    return cfg.out / f"bench-{cfg.split}"


def bench_command(cfg: StudyConfig) -> list[str]:
    cmd = ["drivee2e", "bench", "--suite", cfg.suite, "--split", cfg.split, "--open-loop", "--no-progress",
           "--out", str(bench_dir(cfg))]
    if cfg.limit:
        cmd += ["--limit", str(cfg.limit)]
    for _, spec in policy_specs(cfg):
        cmd += ["--policy", spec]
    return cmd


def evaluate_all(cfg: StudyConfig, log) -> dict | None:
    """One bench run over all policies; skipped when every policy file
    exists. Returns what was run (time, policies to do, controller state),
    None when skipped."""
    bdir = bench_dir(cfg)
    names = [n for n, _ in policy_specs(cfg)]
    missing = [n for n in names if not (bdir / "policies" / f"{n}.json").is_file()]
    if not missing and (bdir / "summary.json").is_file():
        log(f"[eval] {bdir}: all {len(names)} policies done, skipped")
        return None
    for m in cfg.models:
        if epochs_done(cfg.runs / m) < 1:
            raise DriveE2EError(f"{cfg.runs / m}: no checkpoint of {m} to evaluate (train it first)")
    cmd = bench_command(cfg)
    log(f"[eval] {' '.join(cmd)}  (to do: {', '.join(missing)})")
    started = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    controller = controller_state()
    wall = _run(cmd, cfg.out / "logs" / f"bench-{cfg.split}.log")
    return {"started": started, "policies_to_do": missing, "wall_s": round(wall, 1), "controller": controller}


def _run(cmd: list[str], log_file: Path) -> float:
    """Run ``drivee2e ...`` (this interpreter's package), appending its output
    to ``log_file``; returns the wall seconds. A failure is one line."""
    log_file.parent.mkdir(parents=True, exist_ok=True)
    argv = [sys.executable, "-m", "drivee2e_jax.cli", *cmd[1:]] if cmd[0] == "drivee2e" else cmd
    t0 = time.perf_counter()
    with open(log_file, "a", encoding="utf-8") as f:
        f.write(f"$ {' '.join(cmd)}  # {time.strftime('%Y-%m-%d %H:%M:%S %Z')}\n")
        f.flush()
        code = subprocess.call(argv, stdout=f, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - t0
    with open(log_file, "a", encoding="utf-8") as f:
        f.write(f"# exit {code}, {wall:.1f} s wall\n")
    if code != 0:
        raise DriveE2EError(f"`{' '.join(cmd[:3])} ...` failed with exit code {code}; see {log_file}")
    return wall


# ----------------------------------------------------------------------------- tables


def load_policy_rows(bdir: Path, name: str) -> tuple[list[dict], dict]:
    """Per-scenario rows and timing of one finished policy of a bench folder."""
    f = bdir / "policies" / f"{name}.json"
    if not f.is_file():
        raise DriveE2EError(f"{f}: results of policy {name!r} not found (evaluation not finished?)")
    data = json.loads(f.read_text())
    return data["rows"], {"compile_s": data.get("compile_s"), "rollout_s": data.get("wall_s")}


def table4_row(name: str, rows: list[dict], timing: dict, model: str | None, training: dict | None) -> dict:
    """One Table 4 row from a policy's per-scenario rows (``summary.summary_of``)."""
    from drivee2e_jax.eval.summary import summary_of

    o = summary_of(rows)
    l2_1, l2_2 = o.get("l2_1s_stp3"), o.get("l2_2s_stp3")
    coll = o.get("openloop_collision_rate")
    train_s = (training or {}).get("train_loop_s")
    return {
        "policy": name,
        "model": model or "reference",
        "train_epochs": (training or {}).get("epochs"),
        "train_min": None if train_s is None or math.isnan(train_s) else round(train_s / 60.0, 2),
        "l2_1s": l2_1,
        "l2_2s": l2_2,
        "l2_avg": None if l2_1 is None or l2_2 is None else round((l2_1 + l2_2) / 2.0, 4),
        "openloop_collision_pct": None if coll is None else round(100.0 * coll, 4),
        "success_rate": o["success_rate"],
        "driving_score": o["driving_score"],
        "route_completion": o["route_completion"],
        "infraction_score": o["infraction_score"],
        "collisions_per_km": o["collisions_per_km"],
        "eval_s_per_scene": o["eval_time_s"],
        "rollout_s_per_scene": None if not timing.get("rollout_s") else round(timing["rollout_s"] / len(rows), 4),
        "l2_3s": o.get("l2_3s_stp3"),
        "l2_1s_uniad": o.get("l2_1s_uniad"),
        "l2_2s_uniad": o.get("l2_2s_uniad"),
        "num_scenarios": o["num_scenarios"],
        "openloop_samples": o.get("openloop_samples"),
        "compile_s": timing.get("compile_s"),
        "rollout_s": timing.get("rollout_s"),
    }


def behaviour_rows(name: str, rows: list[dict]) -> list[dict]:
    """Per behaviour group (source order, then any other): n, SR %, DS."""
    from drivee2e_jax.eval.summary import summary_of

    groups = [g for g in BEHAVIOURS if any(r["behavior"] == g for r in rows)]
    groups += sorted({r["behavior"] for r in rows} - set(groups))
    out = []
    for g in groups:
        s = summary_of([r for r in rows if r["behavior"] == g], brief=True)
        out.append({"policy": name, "behavior": g, "num_scenarios": s["num_scenarios"],
                    "success_rate": s["success_rate"], "driving_score": s["driving_score"]})
    return out


def build_tables(bdir: Path, policies: list[tuple[str, str | None]], training: dict) -> tuple[list[dict], list[dict]]:
    """Table 4 rows and per-behaviour rows for ``policies`` = [(result name, model or None)]."""
    t4, beh = [], []
    for name, model in policies:
        rows, timing = load_policy_rows(bdir, name)
        t4.append(table4_row(name, rows, timing, model, training.get(model) if model else None))
        beh += behaviour_rows(name, rows)
    return t4, beh


def _fmt(v, decimals) -> str:
    if v is None or v == "" or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if decimals is None:
        return str(v)
    return f"{float(v):.{decimals}f}"


def table4_markdown(rows: list[dict]) -> str:
    head = [h for _, h, _ in TABLE4_COLUMNS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r.get(k), d) for k, _, d in TABLE4_COLUMNS) + " |")
    return "\n".join(lines) + "\n"


def behaviour_markdown(rows: list[dict]) -> str:
    """Two tables, SR % and DS: policies x behaviour groups (group sizes in the header)."""
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    groups = list(dict.fromkeys(r["behavior"] for r in rows))
    size = {}
    for r in rows:
        size.setdefault(r["behavior"], r["num_scenarios"])
    cell = {(r["policy"], r["behavior"]): r for r in rows}
    out = []
    for key, title, dec in (("success_rate", "SR %", 1), ("driving_score", "DS", 2)):
        head = [title] + [f"{g} ({size[g]})" for g in groups]
        out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for p in policies:
            out.append("| " + " | ".join([p] + [_fmt(cell.get((p, g), {}).get(key), dec) for g in groups]) + " |")
        out.append("")
    return "\n".join(out)


def write_tables(out: Path, t4: list[dict], beh: list[dict]) -> None:
    t4_cols = [k for k, _, _ in TABLE4_COLUMNS] + list(TABLE4_EXTRA)
    atomic_write_text(out / "table4.csv", rows_to_csv(t4, t4_cols))
    atomic_write_text(out / "table4.md", table4_markdown(t4))
    atomic_write_text(out / "per_behaviour.csv",
                      rows_to_csv(beh, ("policy", "behavior", "num_scenarios", "success_rate", "driving_score")))
    atomic_write_text(out / "per_behaviour.md", behaviour_markdown(beh))


def controller_state() -> dict:
    """Which waypoint controller the evaluation used: file hash, last commit
    touching it and whether the working tree differs from it."""
    f = REPO / "drivee2e_jax" / "controller.py"
    info = {"file": str(f.relative_to(REPO)), "sha256": hashlib.sha256(f.read_bytes()).hexdigest()[:16] if f.is_file() else None}
    try:
        info["last_commit"] = subprocess.run(["git", "log", "-1", "--format=%h %cI %s", "--", str(f)], cwd=REPO,
                                             capture_output=True, text=True, timeout=20, check=False).stdout.strip()
        info["uncommitted_changes"] = subprocess.run(["git", "diff", "--quiet", "--", str(f)], cwd=REPO,
                                                     timeout=20, check=False).returncode != 0
    except (OSError, subprocess.SubprocessError):
        pass
    info["feed_forward"] = f.is_file() and "feed" in f.read_text().lower()
    return info


# ----------------------------------------------------------------------------- main


def run_study(cfg: StudyConfig, log=None) -> None:
    log = log or (lambda msg: print(msg, flush=True))
    check_inputs(cfg)
    cfg.out.mkdir(parents=True, exist_ok=True)
    prov_file = cfg.out / "provenance.json"
    prov = json.loads(prov_file.read_text()) if prov_file.is_file() else {}
    training = dict(prov.get("training", {}))
    if not cfg.eval_only:  # merged per model: keeps the wall time of a training run by an earlier call
        training.update({m: {**training.get(m, {}), **info} for m, info in train_all(cfg, log).items()})
    else:
        for m in cfg.models:
            training.setdefault(m, {"epochs": epochs_done(cfg.runs / m)})
            training[m]["train_loop_s"] = round(train_time_s(cfg.runs / m / "log.jsonl"), 1)
    prov.update({"training": training, "argv": sys.argv})
    atomic_write_json(prov_file, prov)
    if cfg.train_only:
        return
    done = evaluate_all(cfg, log)
    if done is not None:  # each bench invocation and the controller its rollouts used (append-only)
        with open(cfg.out / "evaluations.jsonl", "a", encoding="utf-8") as f:
            f.write(json.dumps(done) + "\n")
    prov = {**json.loads(prov_file.read_text()), "bench_command": " ".join(bench_command(cfg))}
    atomic_write_json(prov_file, prov)
    pols = [(n, m) for m in cfg.models for n, _ in MODELS[m][2]] + [(r, None) for r in cfg.references]
    t4, beh = build_tables(bench_dir(cfg), pols, training)
    write_tables(cfg.out, t4, beh)
    log(f"wrote {cfg.out / 'table4.md'} and {cfg.out / 'per_behaviour.md'}")
    log(table4_markdown(t4))
    log(behaviour_markdown(beh))


def parse_args(argv: list[str] | None = None) -> StudyConfig:
    p = argparse.ArgumentParser(
        prog="experiments/baselines/run.py",
        description="Train each baseline on twin15 train, evaluate on a split open- and closed-loop, "
        "write Table 4 and the per-behaviour table. Resumable.",
        epilog="example: python experiments/baselines/run.py --out results/baselines --runs runs/baselines",
    )
    p.add_argument("--out", type=Path, required=True, help="tables folder (bench results in OUT/bench-<split>)")
    p.add_argument("--runs", type=Path, default=Path("runs/baselines"), help="training runs folder (default: runs/baselines)")
    p.add_argument("--models", default=",".join(MODELS), help=f"comma-separated (default: {','.join(MODELS)})")
    p.add_argument("--epochs", default="", help="MODEL=N,... (default: " + ",".join(f"{m}={v[1]}" for m, v in MODELS.items()) + ")")
    p.add_argument("--split", default="val", help="evaluation split (default: val)")
    p.add_argument("--suite", default="twin15", help="suite name or folder (default: twin15)")
    p.add_argument("--references", default="", help="more reference policies besides stop,constant_velocity, e.g. log_replay,expert")
    p.add_argument("--limit", type=int, default=None, help="evaluate only the first N scenarios (smoke runs)")
    p.add_argument("--data", action="append", default=[], metavar="MODEL=DIR", help="demonstrations folder of a model (repeatable)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--train-only", action="store_true", help="train, do not evaluate")
    g.add_argument("--eval-only", action="store_true", help="evaluate the existing runs, do not train")
    a = p.parse_args(argv)
    models = parse_models(a.models)
    data = {}
    for item in a.data:
        key, eq, value = item.partition("=")
        if not eq or key not in MODELS:
            raise DriveE2EError(f"--data: expected MODEL=DIR with MODEL one of {', '.join(MODELS)}, got {item!r}")
        data[key] = value
    if a.limit is not None and a.limit < 1:
        raise DriveE2EError(f"--limit: expected >= 1, got {a.limit}")
    return StudyConfig(out=a.out, runs=a.runs, models=models, epochs=parse_epochs(a.epochs, models), split=a.split,
                       suite=a.suite, references=parse_references(a.references), limit=a.limit,
                       train_only=a.train_only, eval_only=a.eval_only, data=data)


def main(argv: list[str] | None = None) -> int:
    try:
        run_study(parse_args(argv))
    except (DriveE2EError, OSError) as e:
        print(f"baselines: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
