"""Reference comfort signals from nuplan-devkit's own code, for tests/metrics/test_comfort_nuplan_reference.py.

nuPlan's simulated ego is driven with its own ``KinematicBicycleModel``
(``propagate_state``: the rear-axle state, its ``DynamicCarState`` with the
centre acceleration derived by ``get_acceleration_shifted``), and the six
comfort signals are computed by the devkit's own ``extract_ego_acceleration``,
``extract_ego_jerk`` and ``extract_ego_yaw_rate`` (their source is taken from
``nuplan/planning/metrics/utils/state_extractors.py`` and executed as is; the
module itself imports the whole simulation stack, so only those functions are
loaded). Two cases, on the project's vehicle geometry (wheelbase 2.9 m, rear
axle to centre 1.45 m = ``dynamics.BicycleParams().lr``), 0.1 s, first-order
delays off (time constants 0, so the commanded acceleration and steer are the
applied ones):

* ``curve``: rear-axle speed 10 m/s, tire angle 0.1 rad held (constant yaw rate);
* ``accelerating_straight``: rear-axle speed 5 m/s, acceleration 1.5 m/s^2, no steer;
* ``accelerating_curve``: 5 m/s, 1 m/s^2, tire angle 0.1 rad (growing yaw rate).

The history starts with the initial state (angular velocity already the
steady one, acceleration the commanded one) as nuPlan's history starts with
the logged state; the test compares rows 1.. with the project's rows (one per
simulated step).

Usage::

    git --git-dir=<nuplan-devkit mirror> archive HEAD nuplan/common \\
        nuplan/planning/simulation/controller nuplan/planning/metrics/utils/state_extractors.py \\
        nuplan/__init__.py nuplan/planning/__init__.py nuplan/planning/simulation/__init__.py | tar x -C SRC
    python experiments/comfort/nuplan_reference.py SRC > tests/data/nuplan_comfort_reference.json

Needs numpy, scipy, shapely (nuPlan's ``EgoState`` builds its footprint).
"""

from __future__ import annotations

import ast
import json
import sys
from pathlib import Path

import numpy as np

WHEELBASE_M = 2.9
DT_S = 0.1
STEPS = 30
CASES = {
    "curve": {"speed": 10.0, "accel": 0.0, "tire_angle": 0.1},
    "accelerating_straight": {"speed": 5.0, "accel": 1.5, "tire_angle": 0.0},
    "accelerating_curve": {"speed": 5.0, "accel": 1.0, "tire_angle": 0.1},
}
EXTRACTORS = ("approximate_derivatives", "phase_unwrap", "extract_ego_heading", "extract_ego_time_point",
              "extract_ego_acceleration", "extract_ego_jerk", "extract_ego_yaw_rate")


def _devkit_extractors(src: Path) -> dict:
    """The devkit's comfort extractors, executed from their own source text."""
    text = (src / "nuplan/planning/metrics/utils/state_extractors.py").read_text()
    tree = ast.parse(text)
    keep = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name in EXTRACTORS]
    assert {n.name for n in keep} == set(EXTRACTORS), [n.name for n in keep]
    from typing import Any

    import numpy.typing as npt
    from nuplan.common.actor_state.ego_state import EgoState
    from scipy.signal import savgol_filter
    ns = {"np": np, "npt": npt, "savgol_filter": savgol_filter, "List": list, "Any": Any, "EgoState": EgoState}
    exec(compile(ast.Module(body=keep, type_ignores=[]), "state_extractors.py", "exec"), ns)  # noqa: S102
    return ns


def run_case(speed: float, accel: float, tire_angle: float) -> dict:
    from nuplan.common.actor_state.dynamic_car_state import DynamicCarState
    from nuplan.common.actor_state.ego_state import EgoState
    from nuplan.common.actor_state.state_representation import StateSE2, StateVector2D, TimePoint
    from nuplan.common.actor_state.vehicle_parameters import VehicleParameters
    from nuplan.planning.simulation.controller.motion_model.kinematic_bicycle import KinematicBicycleModel

    vehicle = VehicleParameters(width=1.9, front_length=3.75, rear_length=0.85, cog_position_from_rear_axle=1.45,
                                wheel_base=WHEELBASE_M, vehicle_name="drivee2e", vehicle_type="car", height=1.5)
    assert abs(vehicle.rear_axle_to_center - 0.5 * WHEELBASE_M) < 1e-12
    model = KinematicBicycleModel(vehicle, accel_time_constant=0.0, steering_angle_time_constant=0.0)
    w0 = speed * np.tan(tire_angle) / WHEELBASE_M
    state = EgoState.build_from_rear_axle(
        rear_axle_pose=StateSE2(0.0, 0.0, 0.0), rear_axle_velocity_2d=StateVector2D(speed, 0.0),
        rear_axle_acceleration_2d=StateVector2D(accel, 0.0), tire_steering_angle=tire_angle,
        time_point=TimePoint(0), vehicle_parameters=vehicle, angular_vel=w0, angular_accel=0.0)
    states = [state]
    for _ in range(STEPS):
        command = DynamicCarState.build_from_rear_axle(
            rear_axle_to_center_dist=vehicle.rear_axle_to_center, rear_axle_velocity_2d=state.dynamic_car_state.rear_axle_velocity_2d,
            rear_axle_acceleration_2d=StateVector2D(accel, 0.0), tire_steering_rate=0.0)
        state = model.propagate_state(state, command, TimePoint(int(DT_S * 1e6)))
        states.append(state)
    ex = _SRC_EXTRACTORS
    dcs = [s.dynamic_car_state for s in states]
    return {
        "t": [s.time_point.time_s for s in states],
        "rear_speed": [d.rear_axle_velocity_2d.x for d in dcs],
        "heading": [s.rear_axle.heading for s in states],
        "rear_accel": [[d.rear_axle_acceleration_2d.x, d.rear_axle_acceleration_2d.y] for d in dcs],
        "center_accel": [[d.center_acceleration_2d.x, d.center_acceleration_2d.y] for d in dcs],
        "angular_velocity": [d.angular_velocity for d in dcs],
        "angular_acceleration": [d.angular_acceleration for d in dcs],
        "signals": {
            "lon_acc": ex["extract_ego_acceleration"](states, acceleration_coordinate="x").tolist(),
            "lat_acc": ex["extract_ego_acceleration"](states, acceleration_coordinate="y").tolist(),
            "jerk": ex["extract_ego_jerk"](states, acceleration_coordinate="magnitude").tolist(),
            "lon_jerk": ex["extract_ego_jerk"](states, acceleration_coordinate="x").tolist(),
            "yaw_rate": ex["extract_ego_yaw_rate"](states).tolist(),
            "yaw_acc": ex["extract_ego_yaw_rate"](states, deriv_order=2, poly_order=3).tolist(),
        },
    }


_SRC_EXTRACTORS: dict = {}

if __name__ == "__main__":
    src = Path(sys.argv[1]).resolve()
    sys.path.insert(0, str(src))
    _SRC_EXTRACTORS.update(_devkit_extractors(src))
    out = {"source": "motional/nuplan-devkit (KinematicBicycleModel.propagate_state, DynamicCarState, "
                     "state_extractors.extract_ego_acceleration / extract_ego_jerk / extract_ego_yaw_rate)",
           "wheelbase_m": WHEELBASE_M, "dt_s": DT_S,
           "cases": {name: {"inputs": c, **run_case(**c)} for name, c in CASES.items()}}
    json.dump(out, sys.stdout, indent=1)
    sys.stdout.write("\n")
