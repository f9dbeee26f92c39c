"""hostapi: numpy containers that mirror types.py, action checks with one-line
errors, the HostPolicy base class and the JAX-free policy-file loader."""

from __future__ import annotations

import dataclasses
import typing

import numpy as np
import pytest

from drivee2e_jax import hostapi, types
from drivee2e_jax.errors import DriveE2EError
from tests.helpers.host_policies import make_observation, write_tiny_policy

WHERE = "my_torch.py, step 7"


def _flax_nested(cls) -> dict[str, type]:
    """Fields of a flax dataclass whose annotation names another types.py dataclass."""
    hints = typing.get_type_hints(cls, vars(types))
    out = {}
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            out[f.name] = hint
    return out


@pytest.mark.parametrize("host_cls", [hostapi.Observation, hostapi.Controls, hostapi.Waypoints])
def test_containers_mirror_types_recursively(host_cls):
    """Same class names, field names, order, nesting and optional fields as
    the flax dataclasses of types.py, all the way down."""
    todo = [(host_cls, getattr(types, host_cls.__name__))]
    seen = set()
    while todo:
        h, f = todo.pop()
        seen.add(h)
        assert h.__name__ == f.__name__
        assert hostapi.field_names(h) == tuple(x.name for x in dataclasses.fields(f)), h.__name__
        h_opt = {x.name for x in dataclasses.fields(h) if x.default is None}
        f_opt = {x.name for x in dataclasses.fields(f) if x.default is None}
        assert h_opt == f_opt, h.__name__
        f_nested = _flax_nested(f)
        h_nested = hostapi._NESTED.get(h, {})
        assert {k: v.__name__ for k, v in h_nested.items()} == {k: v.__name__ for k, v in f_nested.items()}, h.__name__
        todo.extend((h_nested[k], f_nested[k]) for k in h_nested)
    assert seen <= set(hostapi.CONTAINERS)


def test_from_fields_reads_a_types_observation_and_flatten_roundtrips():
    obs = make_observation(3)

    def to_types(value, cls):  # a types.Observation with numpy leaves, built from the host one
        kw = {}
        for name in hostapi.field_names(type(value)):
            v = getattr(value, name)
            nested = _flax_nested(cls)
            kw[name] = to_types(v, nested[name]) if name in nested else v
        return cls(**kw)

    t_obs = to_types(obs, types.Observation)
    back = hostapi.from_fields(t_obs, hostapi.Observation)
    assert isinstance(back.privileged.ego, hostapi.EgoState)
    assert isinstance(back.privileged.log_controls, hostapi.Controls)
    np.testing.assert_array_equal(back.privileged.ego.xy, obs.privileged.ego.xy)
    np.testing.assert_array_equal(back.bev, obs.bev)
    assert back.lidar is None and set(back.sensors) == {"radar"}
    items = hostapi.flatten(obs)
    paths = [p for p, _ in items]
    assert ("privileged", "ego", "xy") in paths and ("sensors", "radar") in paths and ("lidar",) not in paths
    again = hostapi.unflatten(hostapi.Observation, items)
    for (p1, a1), (p2, a2) in zip(items, hostapi.flatten(again)):
        assert p1 == p2 and a1.dtype == a2.dtype
        np.testing.assert_array_equal(a1, a2)
    assert again.batch_size == 3


def test_from_fields_and_unflatten_name_what_is_missing():
    with pytest.raises(DriveE2EError, match="has no field 'brake'"):
        hostapi.from_fields(type("C", (), {"throttle": 1.0, "steer": 0.0})(), hostapi.Controls)
    with pytest.raises(DriveE2EError, match="missing field privileged.ego.t"):
        items = [(p, a) for p, a in hostapi.flatten(make_observation(2)) if p != ("privileged", "ego", "t")]
        hostapi.unflatten(hostapi.Observation, items)
    with pytest.raises(DriveE2EError, match="unknown field"):
        hostapi.unflatten(hostapi.Controls, [(("throttle",), 0), (("brake",), 0), (("steer",), 0), (("gear",), 1)])


# --------------------------------------------------------------------------
# check_action
# --------------------------------------------------------------------------


def _err(action, action_type="controls", batch=4, **kw) -> str:
    with pytest.raises(DriveE2EError) as e:
        hostapi.check_action(action, action_type, batch, WHERE, **kw)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(WHERE + ": "), msg
    return msg


def test_good_actions_become_float32_numpy():
    c = hostapi.check_action(hostapi.Controls(throttle=[0.5] * 4, brake=np.zeros(4, np.int64), steer=np.ones(4)),
                             "controls", 4, WHERE)
    assert isinstance(c, hostapi.Controls)
    assert all(getattr(c, f).dtype == np.float32 and getattr(c, f).shape == (4,) for f in ("throttle", "brake", "steer"))
    w = hostapi.check_action(hostapi.Waypoints(xy=np.zeros((4, 6, 2))), "waypoints", 4, WHERE, num_waypoints=6)
    assert w.xy.dtype == np.float32 and w.xy.shape == (4, 6, 2)


def test_nan_and_inf_are_not_errors():
    nan = np.full(4, np.nan)
    c = hostapi.check_action(hostapi.Controls(throttle=nan, brake=np.full(4, np.inf), steer=nan), "controls", 4, WHERE)
    assert np.isnan(c.throttle).all() and np.isinf(c.brake).all()
    w = hostapi.check_action(hostapi.Waypoints(xy=np.full((4, 2, 2), np.nan)), "waypoints", 4, WHERE)
    assert np.isnan(w.xy).all()


def test_the_flax_classes_are_accepted_too():
    c = hostapi.check_action(types.Controls(throttle=np.zeros(2), brake=np.zeros(2), steer=np.zeros(2)),
                             "controls", 2, WHERE)
    assert isinstance(c, hostapi.Controls)


def test_a_dict_is_an_error():
    msg = _err({"throttle": np.zeros(4), "brake": np.zeros(4), "steer": np.zeros(4)})
    assert "a dict with keys [throttle, brake, steer]" in msg and "Controls(throttle, brake, steer)" in msg


def test_wrong_action_kind_is_an_error():
    msg = _err(hostapi.Controls(np.zeros(4), np.zeros(4), np.zeros(4)), "waypoints")
    assert "Waypoints(xy)" in msg and "a Controls action" in msg and "'waypoints'" in msg
    assert "Controls" in _err(hostapi.Waypoints(np.zeros((4, 3, 2))), "controls")
    assert "a tuple of 2 item(s)" in _err((np.zeros(4), None))
    assert "None" in _err(None)
    assert "numpy.ndarray" in _err(np.zeros((4, 3)))


def test_wrong_shape_is_an_error():
    msg = _err(hostapi.Controls(np.zeros(4), np.zeros((4, 1)), np.zeros(4)))
    assert "Controls.brake has shape (4, 1), expected (4,)" in msg
    msg = _err(hostapi.Waypoints(np.zeros((4, 3, 3))), "waypoints")
    assert "Waypoints.xy has shape (4, 3, 3), expected (4, K, 2)" in msg
    msg = _err(hostapi.Waypoints(np.zeros((4, 6))), "waypoints")
    assert "Waypoints.xy has shape (4, 6), expected (4, K, 2)" in msg
    msg = _err(hostapi.Waypoints(np.zeros((4, 5, 2))), "waypoints", num_waypoints=6)
    assert "has 5 waypoints" in msg and "num_waypoints=6" in msg
    assert "no waypoints" in _err(hostapi.Waypoints(np.zeros((4, 0, 2))), "waypoints")
    assert "has shape ()" in _err(hostapi.Controls(0.0, np.zeros(4), np.zeros(4)))


def test_wrong_batch_is_an_error():
    msg = _err(hostapi.Controls(np.zeros(3), np.zeros(3), np.zeros(3)), batch=4)
    assert "Controls.throttle has batch size 3" in msg and "expected 4" in msg
    msg = _err(hostapi.Waypoints(np.zeros((1, 6, 2))), "waypoints", batch=4)
    assert "Waypoints.xy has batch size 1" in msg


def test_non_numeric_leaves_are_errors():
    assert "Controls.steer is a builtins.str" in _err(hostapi.Controls(np.zeros(4), np.zeros(4), "left"))
    msg = _err(hostapi.Controls(np.array(["a", "b", "c", "d"]), np.zeros(4), np.zeros(4)))
    assert "Controls.throttle has dtype <U1" in msg
    assert "dtype object" in _err(hostapi.Controls(np.array([object()] * 4), np.zeros(4), np.zeros(4)))
    assert "dtype bool" in _err(hostapi.Controls(np.ones(4, bool), np.zeros(4), np.zeros(4)))
    assert "dtype complex128" in _err(hostapi.Controls(np.ones(4, complex), np.zeros(4), np.zeros(4)))
    assert "a dict" in _err(hostapi.Controls({"a": 1}, np.zeros(4), np.zeros(4)))

    class Unreadable:
        def __array__(self, *a, **k):
            raise RuntimeError("can't convert cuda:0 device type tensor to numpy")

    msg = _err(hostapi.Controls(Unreadable(), np.zeros(4), np.zeros(4)))
    assert "numpy cannot read" in msg and "cuda:0" in msg and ".detach().cpu().numpy()" in msg


def test_act_must_return_a_pair():
    with pytest.raises(DriveE2EError, match=r"^my_torch.py, step 7: act\(obs, state\) returned a drivee2e_jax.hostapi.Controls, expected a pair"):
        hostapi.check_act_result(hostapi.Controls(0, 0, 0), WHERE)
    assert hostapi.check_act_result((1, 2), WHERE) == (1, 2)


# --------------------------------------------------------------------------
# HostPolicy and loading
# --------------------------------------------------------------------------


def test_host_policy_defaults_and_reexport():
    from drivee2e_jax.policy import HostPolicy

    assert HostPolicy is hostapi.HostPolicy
    p = HostPolicy()
    assert p.reset([{"scenario_id": "a"}]) is None and p.required_sensors == () and p.action_type == "controls"
    with pytest.raises(NotImplementedError):
        p.act(make_observation(1), None)
    assert hostapi.describe(p) == {"name": "host_policy", "action_type": "controls", "waypoint_dt": 0.5,
                                   "num_waypoints": None, "required_sensors": [], "observation_fields": None}


def test_load_host_policy(tmp_path):
    path = write_tiny_policy(tmp_path)
    pol = hostapi.load_host_policy(path, kind="waypoints")
    assert pol.name == "tiny_waypoints" and pol.num_waypoints == 3 and pol.required_sensors == ("bev",)
    state = pol.reset([{"scenario_id": "a"}, {"scenario_id": "b"}])
    action, state = pol.act(make_observation(2), state)
    assert hostapi.check_action(action, "waypoints", 2, "x", num_waypoints=3).xy.shape == (2, 3, 2)
    with pytest.raises(DriveE2EError, match="make_policy does not take"):
        hostapi.load_host_policy(path, colour="red")


@pytest.mark.parametrize("body, expected", [
    ("class P:\n    def init(self, k, o): ...\n    def initial_state(self, o): ...\n    def act(self, *a): ...\n"
     "policy = P()\n", "a JAX policy"),
    ("policy = 3\n", "the policy is a builtins.int"),
    ("from drivee2e_jax.hostapi import HostPolicy\nclass P(HostPolicy):\n    action_type = 'steering'\npolicy = P()\n",
     "action_type is 'steering'"),
    ("from drivee2e_jax.hostapi import HostPolicy\nclass P(HostPolicy):\n    required_sensors = 'bev'\npolicy = P()\n",
     "required_sensors is 'bev'"),
    ("from drivee2e_jax.hostapi import HostPolicy\nclass P(HostPolicy):\n    action_type = 'waypoints'\n"
     "    waypoint_dt = 0\npolicy = P()\n", "waypoint_dt is 0"),
    ("x = 1\n", "defines neither `policy` nor `make_policy()`"),
    ("raise ValueError('broken file')\n", "importing the policy failed: ValueError: broken file"),
    ("def make_policy():\n    raise OSError('no checkpoint')\n", "make_policy() failed: OSError: no checkpoint"),
])
def test_load_host_policy_errors_are_one_line(tmp_path, body, expected):
    path = tmp_path / "bad_policy.py"
    path.write_text(body)
    with pytest.raises(DriveE2EError) as e:
        hostapi.load_host_policy(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(path)) and expected in msg, msg


def test_missing_file():
    with pytest.raises(DriveE2EError, match="policy file not found"):
        hostapi.load_host_policy("/nonexistent/p.py")


def test_observation_arrays_are_writable_for_torch_from_numpy():
    from types import SimpleNamespace

    route = np.zeros((2, 5, 2), np.float32)
    route.flags.writeable = False  # what a jax callback / jax.device_get hands over
    obs = SimpleNamespace(**{f: None for f in hostapi.field_names(hostapi.Observation)})
    obs.route = route
    out = hostapi.from_fields(obs)
    assert out.route.flags.writeable and np.array_equal(out.route, route)
