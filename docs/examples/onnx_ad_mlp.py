"""AD-MLP exported to ONNX, driven by ONNX Runtime as a host policy (numpy + onnxruntime, no JAX).

    python -c "from drivee2e_jax.models.base import policy_from_checkpoint as p; \
from drivee2e_jax.models.onnx_export import export_ad_mlp as e; \
pol = p('ad_mlp', 'runs/ad_mlp'); e(pol.params, pol.model, 'ad_mlp.onnx')"
    drivee2e bench --policy docs/examples/onnx_ad_mlp.py:model=ad_mlp.onnx
    drivee2e serve-policy docs/examples/onnx_ad_mlp.py:model=ad_mlp.onnx --port 5555  # JAX-free side

The graph (``drivee2e_jax/models/onnx_export.py``) is the MLP only; this file
rebuilds AD-MLP's inputs the way the Flax policy does
(``drivee2e_jax.models.base.ModelPolicy.act``), for the whole batch at once:

* the ego history lives in the policy state (``reset`` -> all invalid), one
  row per scenario, and ``push_history`` appends the current sample when
  ``HISTORY_DT`` = 0.5 s has passed (clock: ``obs.privileged.ego.t``, time
  only) -- ``base.push_history``;
* ``with_history`` expresses it in the current ego frame (gps / compass):
  x, y, cos / sin of the heading change, speed, accel, yaw rate; 0 where
  invalid -- ``base.with_history``;
* ``features`` scales it and appends the scaled ego state and the one-hot
  command -- ``ad_mlp.features``.

Every step is float32, op for op as in JAX, so the per-scenario results
equal the Flax policy's within float rounding
(``tests/models/test_onnx_export.py`` checks it). The constants below are
those of ``drivee2e_jax/models/base.py`` and ``ad_mlp.py``; that test
fails if they drift.
"""

import numpy as np

from drivee2e_jax.hostapi import HostPolicy, Waypoints

F32 = np.float32
#: base.HISTORY_LEN / HISTORY_DT: 8 past samples 0.5 s apart.
HISTORY_LEN = 8
HISTORY_DT = 0.5
#: ad_mlp._HIST_SCALE / _EGO_SCALE / _NUM_COMMANDS.
HIST_SCALE = np.array([0.1, 0.1, 1.0, 1.0, 0.1, 0.2, 1.0], F32)
EGO_SCALE = np.array([0.1, 0.2, 1.0, 1.0], F32)
NUM_COMMANDS = 8
_PI = F32(np.pi)
_TWO_PI = F32(2.0 * np.pi)


def empty_history(b: int) -> dict:
    """All-invalid history of ``b`` scenarios (``base.empty_history``, batched)."""
    h = HISTORY_LEN
    return {"xy": np.zeros((b, h, 2), F32), "yaw": np.zeros((b, h), F32), "ego": np.zeros((b, h, 4), F32),
            "t": np.full((b, h), -1e9, F32), "valid": np.zeros((b, h), bool)}


def push_history(hist: dict, obs) -> dict:
    """``base.push_history`` on a batch: per row, shift in the current sample when due."""
    t = np.asarray(obs.privileged.ego.t, F32)
    due = ~hist["valid"][:, -1] | (t >= (hist["t"][:, -1] + F32(HISTORY_DT)) - F32(1e-3))
    now = {"xy": np.asarray(obs.gps, F32), "yaw": np.asarray(obs.compass, F32), "ego": np.asarray(obs.ego, F32),
           "t": t, "valid": np.ones(t.shape, bool)}
    out = {}
    for key, old in hist.items():
        shifted = np.concatenate([old[:, 1:], now[key][:, None]], axis=1)
        mask = due.reshape((-1,) + (1,) * (old.ndim - 1))
        out[key] = np.where(mask, shifted, old)
    return out


def with_history(hist: dict, obs) -> np.ndarray:
    """(B, H, 7) history in each scenario's current ego frame (``base.with_history``)."""
    gps, compass = np.asarray(obs.gps, F32), np.asarray(obs.compass, F32)
    d = hist["xy"] - gps[:, None]  # geometry.to_frame: rotate(points - origin, -yaw)
    c, s = np.cos(-compass)[:, None], np.sin(-compass)[:, None]
    x, y = d[..., 0], d[..., 1]
    xy = np.stack([c * x - s * y, s * x + c * y], axis=-1)
    a = hist["yaw"] - compass[:, None]
    dyaw = a + _TWO_PI * np.floor((_PI - a) / _TWO_PI)  # geometry.wrap_angle
    feats = np.concatenate([xy, np.cos(dyaw)[..., None], np.sin(dyaw)[..., None], hist["ego"][..., :3]], axis=-1)
    return np.where(hist["valid"][..., None], feats, F32(0.0)).astype(F32)


def features(history: np.ndarray, obs) -> np.ndarray:
    """(B, 68) float32 AD-MLP input (``ad_mlp.features``, batched)."""
    b = history.shape[0]
    hist = (history * HIST_SCALE).reshape(b, -1)
    ego = np.asarray(obs.ego, F32) * EGO_SCALE
    cmd = np.clip(np.asarray(obs.command).astype(np.int64) + 1, 0, NUM_COMMANDS - 1)
    one_hot = (cmd[:, None] == np.arange(NUM_COMMANDS)[None]).astype(F32)
    return np.concatenate([hist, ego, one_hot], axis=-1).astype(F32)


class OnnxADMLP(HostPolicy):
    """AD-MLP's ONNX graph on ONNX Runtime; Waypoints like ``drivee2e_jax/zoo/ad_mlp.py``."""

    action_type = "waypoints"

    def __init__(self, model: str, name: str = "onnx_ad_mlp", threads: int = 1, providers=("CPUExecutionProvider",)):
        # onnxruntime is optional (drivee2e-jax[onnx]): only this example needs it.
        import onnxruntime as ort  # noqa: PLC0415

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = int(threads)  # a tiny MLP: more threads only add overhead
        opts.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(model), sess_options=opts, providers=list(providers))
        props = self.session.get_modelmeta().custom_metadata_map
        if props.get("drivee2e.model") != "ad_mlp":
            raise ValueError(f"{model}: not an AD-MLP export (drivee2e_jax.models.onnx_export.export_ad_mlp)")
        if int(props["drivee2e.history_len"]) != HISTORY_LEN or float(props["drivee2e.history_dt"]) != HISTORY_DT:
            raise ValueError(f"{model}: exported with another ego history than this file's "
                             f"({HISTORY_LEN} samples, {HISTORY_DT} s)")
        self.name = name
        self.num_waypoints = int(props["drivee2e.num_waypoints"])
        self.waypoint_dt = float(props["drivee2e.waypoint_dt"])
        self.input = self.session.get_inputs()[0].name

    def reset(self, meta):
        return {"history": empty_history(len(meta))}

    def act(self, obs, state):
        hist = state["history"] if state and state["history"]["t"].shape[0] == obs.batch_size else None
        hist = push_history(hist if hist is not None else empty_history(obs.batch_size), obs)
        x = features(with_history(hist, obs), obs)
        (xy,) = self.session.run(None, {self.input: x})  # (B, K, 2) ego frame, m
        return Waypoints(xy=np.asarray(xy, F32)), {"history": hist}

    def close(self):
        self.session = None


def make_policy(model: str = "ad_mlp.onnx", name: str = "onnx_ad_mlp", threads: int = 1):
    return OnnxADMLP(model, name=name, threads=int(threads))
