"""Which comfort signal fails, and on what: the simulated ego of a results folder vs its LOGGED ego.

For every episode of a ``drivee2e bench --preset nuplan`` results folder,
prints nuPlan's six comfort signals (``metrics.nuplan.comfort_signals``, the
bounds of ``ego_is_comfortable``) computed three ways:

* ``sim``: the re-simulated ego as the preset scores it (``ego_comfort_inputs``
  on the step log);
* ``log-diff``: the logged ego path differentiated step by step (speed =
  forward difference of the positions along the heading, acceleration = its
  difference): what a one-step position-matching replay must realise;
* ``log-sg``: the logged ego path with a Savitzky-Golay estimate of its
  acceleration in the body frame (``nuplan.path_comfort_inputs``: window 9,
  order 3; jerk on the magnitude), the nearest we have to the IMU
  accelerations nuPlan reads for a logged ego;
* ``log-nuplan``: ``log-sg`` read through nuPlan's centre-acceleration
  formula as the simulated ego is (``ego_comfort_inputs``): lon + lr (w^2 +
  dw/dt), w and dw/dt Savitzky-Golay derivatives of the logged heading
  (window 9, order 3), lat 0, the jerk on |lon| of the path: what a replay
  that follows the log without adding anything of its own scores.

Each signal is printed as ``min..max`` with ``!`` where it leaves nuPlan's
bounds, then per way how many episodes fail and on which signal, and how far
the simulated ego is from its logged position (mean over every step of every
episode, and the largest; the measure of a log replay's fidelity).
usage: python experiments/comfort/diagnose.py RESULTS_DIR [POLICY] [-q (only the counts)]
"""

from __future__ import annotations

import sys
from collections import Counter

import numpy as np
from scipy.signal import savgol_filter

from drivee2e_jax.eval.traces import _run_packed, read_run, trace_episodes
from drivee2e_jax.metrics import nuplan as nm

BOUNDS = {"lon_acc": nm.LON_ACC_BOUNDS, "lat_acc": (-nm.MAX_ABS_LAT_ACC, nm.MAX_ABS_LAT_ACC),
          "jerk": (-nm.MAX_ABS_JERK, nm.MAX_ABS_JERK), "lon_jerk": (-nm.MAX_ABS_LON_JERK, nm.MAX_ABS_LON_JERK),
          "yaw_acc": (-nm.MAX_ABS_YAW_ACC, nm.MAX_ABS_YAW_ACC), "yaw_rate": (-nm.MAX_ABS_YAW_RATE, nm.MAX_ABS_YAW_RATE)}


def line(name: str, sig: dict) -> tuple[str, list[str]]:
    parts, bad = [], []
    for k, (lo, hi) in BOUNDS.items():
        v = sig[k]
        if v is None:
            continue
        out = not np.all((v > lo) & (v < hi))
        bad += [k] if out else []
        parts.append(f"{k} {v.min():+.2f}..{v.max():+.2f}{'!' if out else ''}")
    return f"  {name:9s} " + "  ".join(parts), bad


def logged(xy: np.ndarray, yaw: np.ndarray, dt: float):
    """(t, lon, lat, mag, yaw) of a logged path three ways: step differences, S-G, S-G read as nuPlan's centre."""
    t = np.arange(len(xy)) * dt
    hd = np.stack([np.cos(yaw), np.sin(yaw)], -1)
    step = np.diff(xy, axis=0) / dt
    v = np.concatenate([[(step[0] * hd[0]).sum()], (step * hd[1:]).sum(-1)])
    a = np.diff(v, prepend=v[0]) / dt
    diff = (t, a, np.zeros_like(a), np.abs(a), yaw)
    lon, lat, mag = nm.path_comfort_inputs(xy, yaw, dt)
    w = min(9, len(yaw) if len(yaw) % 2 else len(yaw) - 1)
    if w > 3:
        rate, rate_acc = (savgol_filter(yaw, w, 3, deriv=k, delta=dt) for k in (1, 2))
    else:
        rate = rate_acc = np.zeros_like(yaw)
    centre = lon + 0.5 * nm.DEFAULT_WHEELBASE * (rate**2 + rate_acc)
    return diff, (t, lon, lat, mag, yaw), (t, centre, np.zeros_like(lon), np.abs(lon), yaw)


def main(results: str, policy: str | None = None, quiet: bool = False) -> None:
    run = read_run(results, policy)
    _, packed = _run_packed(run)
    ids = [str(x) for x in packed.meta.scenario_id]
    sc = packed.scenario
    fails = {"sim": 0, "log-diff": 0, "log-sg": 0, "log-nuplan": 0}
    by_signal: dict[str, Counter] = {k: Counter() for k in fails}
    traces = trace_episodes(results, policy, sensors=())
    say = (lambda *a: None) if quiet else print  # noqa: E731
    errors = []  # (scenario, mean m, max m) of the simulated ego's distance to its logged position
    for tr in traces:
        say(f"{tr.scenario_id}  (stored nuplan_ego_is_comfortable {tr.row.get('nuplan_ego_is_comfortable')})")
        # Row 0 of a trace is the reset state; the score reads the rows after each step.
        inputs = nm.ego_comfort_inputs(tr.ego_speed[1:], tr.ego_accel[1:], tr.ego_steer[1:], tr.ego_yaw_rate[1:], tr.dt)
        text, bad = line("sim", nm.comfort_signals(inputs[0], inputs[1], tr.ego_yaw[1:], tr.times[1:], inputs[2]))
        say(text)
        fails["sim"] += bool(bad)
        by_signal["sim"].update(bad)
        i = ids.index(tr.scenario_id)
        e = int(np.asarray(sc.ego_index)[i])
        valid = np.asarray(sc.tracks.valid[i, e], bool)
        xy = np.asarray(sc.tracks.xy[i, e], np.float64)[valid]
        yaw = np.unwrap(np.asarray(sc.tracks.yaw[i, e], np.float64)[valid])
        t_log = np.flatnonzero(valid) * float(np.asarray(sc.dt_log)[i])
        inside = tr.times <= t_log[-1] + 1e-6
        log_at = np.stack([np.interp(tr.times[inside], t_log, xy[:, j]) for j in (0, 1)], -1)
        err = np.linalg.norm(tr.ego_xy[inside] - log_at, axis=-1)
        errors.append((tr.scenario_id, err.mean(), err.max(), len(err)))
        say(f"  distance to the logged position: mean {err.mean():.4f} m, max {err.max():.4f} m")
        for name, (t, lon, lat, mag, hd) in zip(("log-diff", "log-sg", "log-nuplan"), logged(xy, yaw, float(np.asarray(sc.dt_log)[i]))):
            text, bad = line(name, nm.comfort_signals(lon, lat, hd, t, mag))
            say(text)
            fails[name] += bool(bad)
            by_signal[name].update(bad)
    print(f"episodes failing ego_is_comfortable, of {len(traces)}: {fails}")
    for name, c in by_signal.items():
        print(f"  {name}: episodes failing each signal: {dict(c.most_common())}")
    steps = sum(n for *_, n in errors)
    worst = max(errors, key=lambda x: x[2])
    print(f"distance of the simulated ego to its logged position over {steps} steps while logged: "
          f"mean {sum(m * n for _, m, _, n in errors) / steps:.4f} m, max {worst[2]:.4f} m ({worst[0]}); "
          f"episodes with max > 0.1 m: {sum(x[2] > 0.1 for x in errors)}")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "-q"]
    main(args[0], args[1] if len(args) > 1 else None, quiet="-q" in sys.argv)
