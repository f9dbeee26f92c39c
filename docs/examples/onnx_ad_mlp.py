"""AD-MLP exported to ONNX, driven by ONNX Runtime as a host policy (numpy + onnxruntime, no JAX).

    pip install onnx onnxruntime    # exporting needs onnx (and JAX); running the policy only onnxruntime
    python -c "from drivee2e_jax.policy import load_policy; \
from drivee2e_jax.models.onnx_export import export_ad_mlp as e; \
pol = load_policy('ad_mlp'); e(pol.params, pol.model, 'ad_mlp.onnx')"    # the zoo's bundled weights
    drivee2e bench --policy docs/examples/onnx_ad_mlp.py:model=ad_mlp.onnx
    drivee2e serve-policy docs/examples/onnx_ad_mlp.py:model=ad_mlp.onnx --port 5555  # JAX-free side

(``load_policy('ad_mlp:checkpoint=runs/ad_mlp')`` exports your own training run instead.)

The graph (``drivee2e_jax/models/onnx_export.py``) is the MLP only; this file
rebuilds AD-MLP's inputs the way the Flax policy does
(``drivee2e_jax.models.base.ModelPolicy.act``), for the whole batch at once:

* the ego history lives in the policy state (``reset`` -> all invalid), one
  row per scenario, and ``push_history`` appends the current sample when
  ``HISTORY_DT`` = 0.5 s has passed -- ``base.push_history``. The clock is the
  policy's own: it counts its ``act`` calls, ``t = calls * control_every *
  dt`` (``make_policy``'s ``dt`` / ``control_every``, the bench's ``--dt`` /
  ``--control-every``; defaults 0.1 s and 1), in float32 as the simulator
  computes its time. It never reads ``obs.privileged`` (ground truth a
  benchmark policy must not use): ``observation_fields`` lists what it reads,
  and the simulator sends nothing else;
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


def clock(calls: int, dt: float, control_every: int = 1) -> np.float32:
    """The simulator's time at the policy's ``calls``-th query (0 first):
    ``float32(step) * float32(dt)`` with ``step = calls * control_every``, the
    float32 product the simulator's own clock is."""
    return F32(calls * control_every) * F32(dt)


def push_history(hist: dict, obs, t) -> dict:
    """``base.push_history`` on a batch: per row, shift in the current sample
    when due; ``t``: the time now, s (a scalar or one per row)."""
    t = np.broadcast_to(np.asarray(t, F32), hist["t"].shape[:1])
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
    #: All it reads (no ``privileged``): the simulator computes and sends only these.
    observation_fields = ("ego", "gps", "compass", "command")

    def __init__(self, model: str, name: str = "onnx_ad_mlp", threads: int = 1, providers=("CPUExecutionProvider",),
                 dt: float = 0.1, control_every: int = 1):
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
        self.dt, self.control_every = float(dt), int(control_every)
        self.num_waypoints = int(props["drivee2e.num_waypoints"])
        self.waypoint_dt = float(props["drivee2e.waypoint_dt"])
        self.input = self.session.get_inputs()[0].name

    def reset(self, meta):
        return {"history": empty_history(len(meta)), "calls": 0}

    def act(self, obs, state):
        fresh = not state or state["history"]["t"].shape[0] != obs.batch_size
        hist = empty_history(obs.batch_size) if fresh else state["history"]
        calls = 0 if fresh else state["calls"]
        hist = push_history(hist, obs, clock(calls, self.dt, self.control_every))
        x = features(with_history(hist, obs), obs)
        (xy,) = self.session.run(None, {self.input: x})  # (B, K, 2) ego frame, m
        return Waypoints(xy=np.asarray(xy, F32)), {"history": hist, "calls": calls + 1}

    def close(self):
        self.session = None


def make_policy(model: str = "ad_mlp.onnx", name: str = "onnx_ad_mlp", threads: int = 1, dt: float = 0.1,
                control_every: int = 1):
    """``dt`` / ``control_every``: the bench's ``--dt`` / ``--control-every``
    (the policy's clock; pass them when the bench runs with others)."""
    return OnnxADMLP(model, name=name, threads=int(threads), dt=float(dt), control_every=int(control_every))
