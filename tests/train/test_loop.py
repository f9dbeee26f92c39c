"""The Optax training step, Orbax checkpoints and resuming."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models import checkpoint as ckpt
from drivee2e_jax.models.registry import get_model
from drivee2e_jax.train.dataset import DemoDataset
from drivee2e_jax.train.loop import batch_loss, make_optimizer, make_train_step, train


def test_train_step_decreases_loss_on_a_fixed_batch(tiny_demos, small_config):
    model = get_model("ad_mlp", hidden=(32,))
    batch = jax.tree_util.tree_map(jnp.asarray, next(DemoDataset(tiny_demos).batches(8)))
    params = model.init(jax.random.PRNGKey(0), jax.tree_util.tree_map(lambda a: a[0], batch.obs))
    cfg = small_config(tiny_demos, lr=1e-2, warmup_steps=0, end_lr_ratio=1.0)
    opt, _ = make_optimizer(cfg, 40)
    step = make_train_step(model, opt)
    state = opt.init(params)
    first = float(batch_loss(model, params, batch)[0])
    for _ in range(40):
        params, state, loss, metrics = step(params, state, batch)
    assert np.isfinite(first) and float(loss) < 0.5 * first
    assert set(metrics) == {"l1", "l2"}


def test_checkpoint_round_trip(tmp_path):
    import optax

    params = {"params": {"w": jnp.arange(6.0).reshape(2, 3), "b": jnp.ones(3)}}
    opt = optax.adamw(1e-3)
    state = {"params": params, "opt_state": opt.init(params), "step": np.int64(7)}
    ckpt.save(tmp_path, 3, state, {"model": "x"})
    assert ckpt.resolve(tmp_path) == tmp_path / "checkpoints" / "3"
    got = ckpt.restore(ckpt.resolve(tmp_path), state)
    jax.tree_util.tree_map(np.testing.assert_array_equal, got, state)
    assert ckpt.read_meta(tmp_path / "checkpoints" / "3") == {"model": "x", "epoch": 3}
    with pytest.raises(DriveE2EError, match="no checkpoint"):
        ckpt.resolve(tmp_path / "nothing")


def test_run_folder_and_resume(tiny_demos, tiny_run, tmp_path, small_config):
    """Interrupt after epoch 1, resume: same step count and the very same
    parameters as the uninterrupted run (deterministic seeds)."""
    cfg = small_config(tiny_demos)
    spe = DemoDataset(tiny_demos).steps_per_epoch(cfg.batch_size)
    assert [p.name for p in ckpt.list_checkpoints(tiny_run)] == ["1", "2"]
    assert ckpt.read_meta(tiny_run / "checkpoints" / "2")["step"] == 2 * spe
    log = [json.loads(ln) for ln in (tiny_run / "log.jsonl").read_text().splitlines()]
    assert {"step", "epoch", "loss", "lr", "metrics", "time"} <= set(log[0])

    import shutil

    shutil.copytree(tiny_run, tmp_path / "run")
    shutil.rmtree(tmp_path / "run" / "checkpoints" / "2")
    res = train(cfg, tmp_path / "run", resume=True, print_fn=lambda s: None)
    assert res["steps"] == 2 * spe
    a = ckpt.load_params(tiny_run)
    b = ckpt.load_params(tmp_path / "run")
    jax.tree_util.tree_map(lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-7), a, b)
    steps = [r["step"] for r in map(json.loads, (tmp_path / "run" / "log.jsonl").read_text().splitlines())
             if "event" not in r]
    assert steps == sorted(set(steps))  # no duplicated lines after the resume

    with pytest.raises(DriveE2EError, match="changed config.*lr"):
        train(small_config(tiny_demos, lr=5e-3), tmp_path / "run", resume=True)
    with pytest.raises(DriveE2EError, match="already exists"):
        train(cfg, tmp_path / "run")


def test_a_run_folder_holding_other_files_is_never_written_or_cleared(tmp_path):
    """train / rl / finetune (``check_run_dir``): a non-empty folder without
    config.json is never written to; --force clears only a run's own files."""
    from drivee2e_jax.train.loop import check_run_dir

    out = tmp_path / "run"
    out.mkdir()
    (out / "log.jsonl").write_text("the user's notes\n")
    for force in (False, True):
        with pytest.raises(DriveE2EError, match=rf"^{out}: not a drivee2e training run folder \(no config.json; "
                                                r"holds log.jsonl\)"):
            check_run_dir(out, {}, resume=False, force=force)
    (out / "config.json").write_text("{}")
    (out / "checkpoints" / "1" / "state").mkdir(parents=True)
    (out / "checkpoints" / "1" / "state" / "x").write_text("")
    (out / "checkpoints" / "mine.txt").write_text("the user's")
    with pytest.raises(DriveE2EError, match=r"holds files drivee2e did not write \(checkpoints/mine.txt\)"):
        check_run_dir(out, {}, resume=False, force=True)
    assert (out / "checkpoints" / "1" / "state" / "x").exists() and (out / "log.jsonl").exists()
    (out / "checkpoints" / "mine.txt").unlink()
    check_run_dir(out, {}, resume=False, force=True)
    assert sorted(p.name for p in out.iterdir()) == []  # a run's own files: cleared
