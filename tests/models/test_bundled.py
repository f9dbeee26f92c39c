"""Bundled zoo weights (``models/bundled.py``, ``zoo/_weights.py`` and the
learned zoo files): export a checkpoint, load it back bit for bit, refuse a
corrupted or incomplete pair in one line, and drive the same as the checkpoint.

Every test points ``DRIVEE2E_ZOO_WEIGHTS`` at a tmp folder: nothing is
written into the package, and the package's own weights (if any) are not read.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax import SimConfig, Simulator
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models import bundled as bw
from drivee2e_jax.models import checkpoint as ckpt
from drivee2e_jax.models.base import policy_from_checkpoint
from drivee2e_jax.policy import load_policy, reference_policy_dir, reference_policy_names
from tests.helpers import sim_scenarios as ss

REPO = Path(__file__).resolve().parents[2]
ZOO = reference_policy_dir()
CONFIG = dict(dim=16, heads=2, layers=1)
INFO = {"mode": "traj", "training": {"command": "drivee2e train --model vector_transformer", "epochs": 2},
        "val": {"driving_score": 50.0, "success_rate": 20.0, "route_completion": 70.5},
        "measured_with": "drivee2e bench --policy vector_transformer --split val"}


@pytest.fixture(scope="module")
def obs():
    """The first observation of a hand-built straight-road scenario."""
    batch = ss.build([ss.clean()])
    scn = jax.tree_util.tree_map(lambda a: jnp.asarray(a[0]), batch.scenario)
    _, o = jax.jit(Simulator(SimConfig()).reset)(jax.random.PRNGKey(0), scn)  # op by op: ~25 s
    return o


@pytest.fixture(scope="module")
def run(tmp_path_factory, obs) -> Path:
    """A training-like run folder: a small vector_transformer's params, an
    optimiser state and a step (epoch 2)."""
    params = policy_from_checkpoint("vector_transformer", None, "traj", **CONFIG).init(jax.random.PRNGKey(1), obs)
    out = tmp_path_factory.mktemp("run")
    state = {"params": params, "opt_state": {"mu": params, "count": np.int64(3)}, "step": np.int64(5)}
    ckpt.save(out, 2, state, {"model": "vector_transformer", "model_config": CONFIG})
    return out


@pytest.fixture
def weights(tmp_path, monkeypatch) -> Path:
    """An empty weights folder, made the zoo's (``DRIVEE2E_ZOO_WEIGHTS``)."""
    d = tmp_path / "weights"
    d.mkdir()
    monkeypatch.setenv(bw.WEIGHTS_ENV, str(d))
    return d


def test_export_then_load_gives_the_params_bit_for_bit(run, weights):
    npz, jpath = bw.export_bundled(run, "vector_transformer", weights, INFO)
    assert (npz, jpath) == (weights / "vector_transformer.npz", weights / "vector_transformer.json")
    info = json.loads(jpath.read_text())
    assert (info["name"], info["model"], info["model_config"], info["mode"], info["format"]) == (
        "vector_transformer", "vector_transformer", CONFIG, "traj", 1)
    assert info["sha256"] == bw.sha256_file(npz) and info["val"] == INFO["val"] and info["data_bev"] is None
    assert info["source"]["epoch"] == 2 and info["source"]["checkpoint"].endswith("checkpoints/2")
    with np.load(npz) as z:  # the parameters only, '/'-joined keys
        assert z.files and all(k.startswith("params/") for k in z.files)
    model, config, params = bw.load_bundled("vector_transformer")
    want = ckpt.restore(ckpt.resolve(run))["params"]
    assert (model, config) == ("vector_transformer", CONFIG)
    assert jax.tree_util.tree_structure(params) == jax.tree_util.tree_structure(want)
    for got, ref in zip(jax.tree_util.tree_leaves(params), jax.tree_util.tree_leaves(want)):
        assert got.dtype == np.float32 and got.shape == ref.shape
        np.testing.assert_array_equal(got, ref)
    assert info["n_params"] == sum(x.size for x in jax.tree_util.tree_leaves(want))


def test_export_is_reproducible_byte_for_byte(run, tmp_path):
    a, _ = bw.export_bundled(run, "vt", tmp_path / "a", INFO)
    b, _ = bw.export_bundled(run, "vt", tmp_path / "b", {**INFO, "val": None})
    assert a.read_bytes() == b.read_bytes()


def _one_line_naming(exc: pytest.ExceptionInfo, path: Path) -> None:
    assert "\n" not in str(exc.value) and str(exc.value).startswith(f"{path}: "), str(exc.value)


def test_a_corrupted_missing_or_bad_pair_is_refused_in_one_line(run, weights):
    npz, jpath = bw.export_bundled(run, "vector_transformer", weights, INFO)
    data = bytearray(npz.read_bytes())
    data[len(data) // 2] ^= 0xFF
    npz.write_bytes(bytes(data))
    with pytest.raises(DriveE2EError, match="sha256 .* does not match") as e:
        bw.load_bundled("vector_transformer")
    _one_line_naming(e, npz)
    with pytest.raises(DriveE2EError, match="sha256"):  # the zoo file goes through the same check
        load_policy(ZOO / "vector_transformer.py")
    npz.unlink()
    with pytest.raises(DriveE2EError, match="bundled weights missing") as e:
        bw.load_bundled("vector_transformer")
    _one_line_naming(e, npz)
    jpath.write_text("{not json")
    with pytest.raises(DriveE2EError, match="unreadable") as e:
        bw.load_bundled("vector_transformer")
    _one_line_naming(e, jpath)
    jpath.write_text(json.dumps({"format": 1, "name": "vector_transformer", "model": "vector_transformer"}))
    with pytest.raises(DriveE2EError, match="'model_config' missing") as e:
        bw.load_bundled("vector_transformer")
    _one_line_naming(e, jpath)
    jpath.unlink()
    with pytest.raises(DriveE2EError, match="metadata missing") as e:
        bw.load_bundled("vector_transformer")
    _one_line_naming(e, jpath)


def test_export_refuses_a_bad_name_mode_or_val(run, tmp_path):
    with pytest.raises(DriveE2EError, match="name 'Bad-Name'"):
        bw.export_bundled(run, "Bad-Name", tmp_path, INFO)
    with pytest.raises(DriveE2EError, match="info\\['mode'\\]"):
        bw.export_bundled(run, "vt", tmp_path, {**INFO, "mode": "waypoints"})
    with pytest.raises(DriveE2EError, match="info\\['val'\\]"):
        bw.export_bundled(run, "vt", tmp_path, {**INFO, "val": {"driving_score": 1.0}})
    with pytest.raises(DriveE2EError, match="info\\['variants'\\]\\['vt_x'\\]"):
        bw.export_bundled(run, "vt", tmp_path, {**INFO, "variants": {"vt_x": {"driving_score": 1.0}}})
    with pytest.raises(DriveE2EError, match="info\\['variants'\\]: name 'Bad'"):
        bw.export_bundled(run, "vt", tmp_path, {**INFO, "variants": {"Bad": None}})
    with pytest.raises(DriveE2EError, match="no checkpoint found"):
        bw.export_bundled(tmp_path / "nothing", "vt", tmp_path, INFO)
    assert not list(tmp_path.glob("vt.*"))


def test_flatten_refuses_what_it_could_not_split_back():
    with pytest.raises(DriveE2EError, match="key 'a/b'"):
        bw.flatten_params({"a/b": np.zeros(2)})
    with pytest.raises(DriveE2EError, match="empty dict at x"):
        bw.flatten_params({"x": {}})
    with pytest.raises(DriveE2EError, match="int64, expected floating"):
        bw.flatten_params({"n": np.arange(3)})
    tree = {"a": {"b": np.ones(2, np.float32), "c": {"d": np.zeros((2, 3), np.float32)}}, "e": np.ones(1, np.float32)}
    assert jax.tree_util.tree_structure(bw.unflatten_params(bw.flatten_params(tree))) == \
        jax.tree_util.tree_structure(tree)


@pytest.mark.parametrize("name", ["vector_transformer", "vector_transformer_ft", "ppo"])
def test_the_zoo_policy_from_bundled_weights_acts_as_from_the_checkpoint(run, weights, obs, name):
    bw.export_bundled(run, name, weights, INFO)
    bundled = load_policy(ZOO / f"{name}.py")
    from_ckpt = load_policy(ZOO / f"{name}.py", checkpoint=str(run))
    assert (bundled.name, bundled.action_type, bundled.model) == (name, "waypoints", from_ckpt.model)
    key = jax.random.PRNGKey(2)
    acts = []
    for pol in (bundled, from_ckpt):
        params = pol.init(key, obs)
        action, _ = pol.act(params, obs, pol.initial_state(obs), key)
        acts.append(np.asarray(action.xy))
    assert acts[0].shape == (6, 2) and np.isfinite(acts[0]).all()
    np.testing.assert_array_equal(acts[0], acts[1])


def test_without_bundled_weights_each_zoo_file_keeps_its_old_behaviour(weights, monkeypatch, run):
    monkeypatch.delenv("DRIVEE2E_AD_MLP_CHECKPOINT", raising=False)
    assert load_policy(ZOO / "vector_transformer.py", **CONFIG).params is None  # random init (smoke tests)
    with pytest.raises(DriveE2EError, match="checkpoint=.*DRIVEE2E_AD_MLP_CHECKPOINT.*ad_mlp.npz missing"):
        load_policy(ZOO / "ad_mlp.py")
    for name in ("vector_transformer_ft", "ppo", "ppo_scratch"):
        with pytest.raises(DriveE2EError, match=f"{weights / name}.npz missing") as e:
            load_policy(ZOO / f"{name}.py")
        assert "\n" not in str(e.value)
    bw.export_bundled(run, "vector_transformer", weights, INFO)  # bundled=False still draws a random init
    assert load_policy(ZOO / "vector_transformer.py", bundled=False, **CONFIG).params is None
    assert load_policy(ZOO / "vector_transformer.py").params is not None


def test_weights_of_another_model_are_refused(run, weights):
    bw.export_bundled(run, "tcp", weights, INFO)  # vector_transformer weights under the tcp name
    with pytest.raises(DriveE2EError, match="tcp.json: weights of a 'vector_transformer' model, expected 'tcp'"):
        load_policy(ZOO / "tcp_traj.py")  # ...found through tcp_traj's fallback to the tcp pair


def test_the_new_names_are_zoo_names():
    assert {"vector_transformer_ft", "ppo", "ppo_scratch", "vector_mlp"} <= set(reference_policy_names())
    assert not any(n.startswith("_") for n in reference_policy_names())


def test_loading_bundled_weights_imports_no_jax(run, tmp_path):
    bw.export_bundled(run, "vector_transformer", tmp_path, INFO)
    program = ("import sys; from drivee2e_jax.models.bundled import load_bundled; "
               f"m, c, p = load_bundled('vector_transformer', {str(tmp_path)!r}); "
               "print(m, sorted(x for x in ('jax', 'flax', 'orbax') if x in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "vector_transformer []"


def test_the_export_script_writes_the_pair(run, tmp_path):
    script = REPO / "experiments" / "zoo" / "export.py"
    proc = subprocess.run([sys.executable, str(script), str(run), "ppo", "--mode", "traj", "--out", str(tmp_path),
                           "--steps", "40", "--val-ds", "1", "--val-sr", "2", "--val-rc", "3",
                           "--variant", "ppo_x=4,5,6"],
                          capture_output=True, text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-2000:]
    info = json.loads((tmp_path / "ppo.json").read_text())
    assert info["val"] == {"driving_score": 1.0, "success_rate": 2.0, "route_completion": 3.0}
    assert info["training"]["steps"] == 40 and info["measured_with"] == "drivee2e bench --policy ppo --split val"
    assert info["variants"] == {"ppo_x": {"driving_score": 4.0, "success_rate": 5.0, "route_completion": 6.0}}
    bad = subprocess.run([sys.executable, str(script), str(run), "ppo", "--mode", "traj", "--out", str(tmp_path),
                          "--val-ds", "1"], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert bad.returncode == 2 and bad.stderr.strip().endswith("go together (all three or none)")
    bad = subprocess.run([sys.executable, str(script), str(run), "ppo", "--mode", "traj", "--out", str(tmp_path),
                          "--variant", "ppo_x=4,5"], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert bad.returncode == 2 and "expected NAME=DS,SR,RC" in bad.stderr and bad.stderr.count("\n") == 1


def test_a_results_folder_fingerprints_the_bundled_weights(run, weights):
    """Results of a zoo policy made before its weights changed are not resumed
    as if the same inputs produced them (eval.results.policy_fingerprint)."""
    from drivee2e_jax.eval.results import policy_fingerprint
    from drivee2e_jax.policy import resolve_policy_path

    path = resolve_policy_path("tcp_traj")
    before = policy_fingerprint(path, {})
    assert "bundled_sha256" not in before
    bw.export_bundled(run, "tcp", weights, INFO)  # tcp_traj falls back to its family's weights
    after = policy_fingerprint(path, {})
    assert set(after["bundled_sha256"]) == {"tcp.npz", "tcp.json"} and after != before
    assert "bundled_sha256" not in policy_fingerprint(path, {"checkpoint": str(run)})  # a checkpoint decides
    assert "bundled_sha256" not in policy_fingerprint(resolve_policy_path("stop"), {})
