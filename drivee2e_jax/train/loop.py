"""Imitation training: Optax AdamW + warmup-cosine, a jitted step, Orbax checkpoints per epoch.

``train(TrainConfig(...), out)`` is what ``drivee2e train`` calls. The loss of
a batch is the mean of ``model.loss`` vmapped over its samples. With more
than one local device the batch is sharded over a 1-D ``data`` mesh
(``jax.sharding``; parameters replicated), so XLA inserts the gradient
all-reduce; on one device it is a plain jit.

Run folder::

    RUN/config.json            the TrainConfig (+ data digest); a resumed run must match it
    RUN/log.jsonl              {"step", "epoch", "loss", "lr", "metrics", "time"} per logged step,
                               {"event": "epoch", ...} per finished epoch
    RUN/checkpoints/<epoch>/   ``train.checkpoint`` (params, opt_state, step + meta.json)

Deterministic: parameter init from ``seed``, batch order from (seed, epoch).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import (
    ForeignFiles,
    OwnFolder,
    atomic_write_json,
    atomic_write_text,
    check_own_folder,
    loads_json,
)
from drivee2e_jax.jsonfile import read_json
from drivee2e_jax.models import checkpoint as ckpt
from drivee2e_jax.models.registry import get_model
from drivee2e_jax.progress import ProgressFn
from drivee2e_jax.train.dataset import DemoDataset


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """One training run (CLI flags map one to one).

    Attributes:
      model: registry name (``models.MODELS``).  model_config: (key, value)
        pairs passed to the model's ``make_model``.
      data: demonstration dataset folder (``train.dataset``).
      epochs: passes over the data.  batch_size: samples per step.
      lr: peak learning rate; linear warmup over ``warmup_steps`` then cosine
        decay to ``lr * end_lr_ratio`` at the last step.
      weight_decay: AdamW decoupled weight decay.  grad_clip: global-norm clip.
      seed: init and shuffling seed.  log_every: steps between log lines.
    """

    model: str = "ad_mlp"
    model_config: tuple = ()
    data: str = ""
    epochs: int = 3
    batch_size: int = 256
    lr: float = 1e-3
    warmup_steps: int = 50
    end_lr_ratio: float = 0.01
    weight_decay: float = 1e-4
    grad_clip: float = 1.0
    seed: int = 0
    log_every: int = 10

    def __post_init__(self):
        if self.epochs < 1 or self.batch_size < 1:
            raise DriveE2EError(f"train: epochs and batch_size must be >= 1, got {self.epochs}, {self.batch_size}")
        if not self.lr > 0:
            raise DriveE2EError(f"train: lr must be > 0, got {self.lr}")

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["model_config"] = dict(self.model_config)
        return d


def make_optimizer(cfg: TrainConfig, total_steps: int) -> tuple[optax.GradientTransformation, Callable]:
    """(AdamW with global-norm clipping, its learning-rate schedule)."""
    warmup = min(cfg.warmup_steps, max(total_steps - 1, 0))
    schedule = optax.warmup_cosine_decay_schedule(
        0.0, cfg.lr, warmup, max(total_steps, warmup + 1), end_value=cfg.lr * cfg.end_lr_ratio
    )
    opt = optax.chain(optax.clip_by_global_norm(cfg.grad_clip), optax.adamw(schedule, weight_decay=cfg.weight_decay))
    return opt, schedule


def batch_loss(model, params, batch) -> tuple[jnp.ndarray, dict]:
    """Mean of ``model.loss`` over a batch ``Sample`` (leading axis B)."""
    losses, metrics = jax.vmap(model.loss, in_axes=(None, 0, 0))(params, batch.obs, batch.target)
    return jnp.mean(losses), jax.tree_util.tree_map(jnp.mean, metrics)


def make_train_step(model, opt: optax.GradientTransformation) -> Callable:
    """jit((params, opt_state, batch) -> (params, opt_state, loss, metrics))."""

    def step(params, opt_state, batch):
        (loss, metrics), grads = jax.value_and_grad(lambda p: batch_loss(model, p, batch), has_aux=True)(params)
        updates, opt_state = opt.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, loss, metrics

    return jax.jit(step)


def data_sharding(batch_size: int):
    """(batch sharding, replicated sharding) over the local devices, or
    (None, None) on one device. Raises when the batch does not split evenly."""
    devices = jax.local_devices()
    if len(devices) < 2:
        return None, None

    if batch_size % len(devices):
        raise DriveE2EError(f"train: --batch-size {batch_size} must be a multiple of the {len(devices)} devices")
    mesh = Mesh(np.asarray(devices), ("data",))
    return NamedSharding(mesh, PartitionSpec("data")), NamedSharding(mesh, PartitionSpec())


#: What a training run folder holds (``train``, ``rl``, ``finetune``): a
#: non-empty folder without config.json is never written to, and ``--force``
#: clears only a folder with no other files than these (``files.check_own_folder``).
TRAINING_FOLDER = OwnFolder("training run", "config.json", ("config.json", "log.jsonl", "checkpoints/*/**"))


def check_run_dir(out: Path, cfg_json: dict, resume: bool, force: bool) -> None:
    """Check ``out`` before a training run writes it: new or empty, or a
    training run folder (``TRAINING_FOLDER``) that ``resume`` continues with
    the same config or ``force`` clears (only when it holds nothing else).
    DriveE2EError (one line) otherwise."""
    try:
        check_own_folder(out, TRAINING_FOLDER, redo=force)
    except ForeignFiles as e:
        raise DriveE2EError(str(e)) from None
    cfg_file = out / "config.json"
    if not cfg_file.is_file():
        return
    if force:

        for name in ("checkpoints", "log.jsonl", "config.json"):
            p = out / name
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()
        return
    if not resume:
        raise DriveE2EError(f"{out}: a training run already exists (--resume to continue it, --force to restart)")
    old = read_json(cfg_file)  # BadJSON: one line naming the file
    diff = sorted(k for k in set(old) | set(cfg_json) if old.get(k) != cfg_json.get(k))
    if diff:
        raise DriveE2EError(f"{out}: --resume with a changed config ({', '.join(f'{k}: {old.get(k)!r} -> {cfg_json.get(k)!r}' for k in diff)})")


def trim_log(log: Path, step: int) -> None:
    """Drop log lines past ``step`` (written after the checkpoint we resume from)."""
    if not log.is_file():
        return
    keep = [ln for ln in log.read_text().splitlines() if ln.strip() and loads_json(ln).get("step", 0) <= step]
    atomic_write_text(log, "".join(ln + "\n" for ln in keep))


def train(cfg: TrainConfig, out: str | Path, *, resume: bool = False, force: bool = False,
          progress: ProgressFn | None = None, print_fn: Callable[[str], None] = print) -> dict:
    """Train ``cfg.model`` on ``cfg.data``, writing the run folder ``out``.

    ``progress(f"epoch {e}/{E}", step_in_epoch, steps_per_epoch, {"loss": ...})``
    after every optimiser step (``progress.ProgressFn``; the CLI draws bars).

    Returns {"epochs", "steps", "loss", "wall_s", "checkpoints"}.
    """

    out = Path(out)
    ds = DemoDataset(cfg.data)
    model = get_model(cfg.model, **dict(cfg.model_config))
    ds.check_model(model, cfg.model)
    steps_per_epoch = ds.steps_per_epoch(cfg.batch_size)
    if steps_per_epoch < 1:
        raise DriveE2EError(f"{cfg.data}: {len(ds)} samples, fewer than one batch of {cfg.batch_size}")
    cfg_json = json.loads(json.dumps({**cfg.to_json(), "data_digest": ds.digest}))
    check_run_dir(out, cfg_json, resume, force)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "config.json", cfg_json)

    opt, schedule = make_optimizer(cfg, cfg.epochs * steps_per_epoch)
    k_init = jax.random.PRNGKey(cfg.seed)
    params = model.init(k_init, jax.device_put(ds.first().obs))
    opt_state = opt.init(params)
    step, start_epoch = 0, 0
    done = ckpt.list_checkpoints(out)
    if done:
        state = ckpt.restore(done[-1], {"params": params, "opt_state": opt_state, "step": np.int64(0)})
        params, opt_state, step = state["params"], state["opt_state"], int(state["step"])
        start_epoch = int(ckpt.read_meta(done[-1])["epoch"])
        trim_log(out / "log.jsonl", step)
        print_fn(f"resuming {out} from epoch {start_epoch} (step {step})")
    batch_sh, repl_sh = data_sharding(cfg.batch_size)
    if repl_sh is not None:
        params, opt_state = jax.device_put((params, opt_state), repl_sh)
    train_step = make_train_step(model, opt)

    t0 = time.perf_counter()
    loss = float("nan")
    with open(out / "log.jsonl", "a", encoding="utf-8") as log:
        for epoch in range(start_epoch + 1, cfg.epochs + 1):
            losses = []
            for batch in ds.batches(cfg.batch_size, seed=cfg.seed, epoch=epoch):
                batch = jax.device_put(batch, batch_sh) if batch_sh is not None else batch
                params, opt_state, loss_value, metrics = train_step(params, opt_state, batch)
                step += 1
                loss = float(loss_value)
                losses.append(loss)
                if progress is not None:
                    progress(f"epoch {epoch}/{cfg.epochs}", len(losses), steps_per_epoch, {"loss": f"{loss:.4f}"})
                if step % cfg.log_every == 0 or step == 1:
                    row = {"step": step, "epoch": epoch, "loss": loss, "lr": float(schedule(step - 1)),
                           "metrics": {k: float(v) for k, v in metrics.items()},
                           "time": round(time.perf_counter() - t0, 3)}
                    log.write(json.dumps(row) + "\n")
                    log.flush()
            meta = {"step": step, "model": cfg.model, "model_config": dict(cfg.model_config),
                    "config": cfg_json, "data_digest": ds.digest, "data_bev": ds.manifest.get("bev"),
                    "train_loss": float(np.mean(losses))}
            ckpt.save(out, epoch, {"params": params, "opt_state": opt_state, "step": np.int64(step)}, meta)
            log.write(json.dumps({"event": "epoch", "step": step, "epoch": epoch, "loss": float(np.mean(losses)),
                                  "time": round(time.perf_counter() - t0, 3)}) + "\n")
            log.flush()
            print_fn(f"epoch {epoch}: mean loss {np.mean(losses):.4f}, step {step}, "
                     f"{time.perf_counter() - t0:.1f} s -> {ckpt.checkpoint_dir(out, epoch)}")
    return {"epochs": cfg.epochs, "steps": step, "loss": loss, "wall_s": time.perf_counter() - t0,
            "checkpoints": [str(p) for p in ckpt.list_checkpoints(out)]}


def model_of_run(run_dir: str | Path) -> Any:
    """The model a run folder trained (from its ``config.json``)."""

    f = Path(run_dir) / "config.json"
    if not f.is_file():
        raise DriveE2EError(f"{f}: not a training run folder (no config.json)")
    cfg = read_json(f)  # BadJSON: one line naming the file
    if not isinstance(cfg, dict) or not isinstance(cfg.get("model"), str):
        raise DriveE2EError(f"{f}: expected a JSON object with \"model\" (a model name), as `drivee2e train` writes it")
    return get_model(cfg["model"], **cfg.get("model_config", {}))
