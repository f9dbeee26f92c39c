"""Small hand-written importer inputs shared by the importer tests
(``tests/scenario/importers``) and the ``drivee2e suite import`` CLI tests
(``tests/cli/test_suite_import.py``): an OpenDRIVE junction, INTERACTION
track CSVs along a lane, ScenarioNet scenario dicts and pickles."""

from __future__ import annotations

import math
import pickle
from pathlib import Path

import numpy as np

# --------------------------------------------------------------------------
# OpenDRIVE (+ INTERACTION tracks)
# --------------------------------------------------------------------------

XODR_HEAD = '<?xml version="1.0"?>\n<OpenDRIVE><header revMajor="1" revMinor="6"/>\n'

JUNCTION = XODR_HEAD + """
<road id="1" length="50" junction="-1">
  <link><successor elementType="junction" elementId="100"/></link>
  <planView><geometry s="0" x="0" y="0" hdg="0" length="50"><line/></geometry></planView>
  <lanes><laneSection s="0">
    <left><lane id="1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></left>
    <center><lane id="0" type="none"><roadMark sOffset="0" type="solid"/></lane></center>
    <right><lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right>
  </laneSection></lanes>
</road>
<road id="2" length="31.41592653589793" junction="100">
  <planView><geometry s="0" x="50" y="0" hdg="0" length="31.41592653589793"><arc curvature="0.05"/></geometry></planView>
  <lanes><laneSection s="0">
    <center><lane id="0" type="none"/></center>
    <right><lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right>
  </laneSection></lanes>
</road>
<road id="3" length="50" junction="-1">
  <planView><geometry s="0" x="70" y="20" hdg="1.5707963267948966" length="50"><line/></geometry></planView>
  <lanes><laneSection s="0">
    <left><lane id="1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></left>
    <center><lane id="0" type="none"><roadMark sOffset="0" type="solid"/></lane></center>
    <right><lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right>
  </laneSection></lanes>
</road>
<junction id="100"><connection id="0" incomingRoad="1" connectingRoad="2" contactPoint="start">
  <laneLink from="-1" to="-1"/></connection></junction>
</OpenDRIVE>
"""


def interaction_csv(path: Path, lane_xy: np.ndarray, speed: float = 8.0) -> None:
    """A car driving along ``lane_xy`` at ``speed`` (INTERACTION vehicle_tracks format)."""
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(lane_xy, axis=0), axis=1))]
    rows = ["track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,psi_rad,length,width"]
    for f, d in enumerate(np.arange(0.0, s[-1] - 1.0, speed * 0.1)):
        x, y = np.interp(d, s, lane_xy[:, 0]), np.interp(d, s, lane_xy[:, 1])
        x2, y2 = np.interp(d + 0.5, s, lane_xy[:, 0]), np.interp(d + 0.5, s, lane_xy[:, 1])
        h = math.atan2(y2 - y, x2 - x)
        rows.append(f"1,{f + 1},{f * 100},car,{x:.3f},{y:.3f},{speed * math.cos(h):.3f},{speed * math.sin(h):.3f},"
                    f"{h:.4f},4.5,1.8")
    path.write_text("\n".join(rows) + "\n")


# --------------------------------------------------------------------------
# ScenarioNet
# --------------------------------------------------------------------------


def _state(n, xy, heading=0.0, valid=None, size=(4.5, 1.9, 1.6)):
    return {
        "position": np.concatenate([xy, np.zeros((n, 1))], 1),
        "heading": np.full(n, heading),
        "velocity": np.zeros((n, 2)),
        "valid": np.ones(n) if valid is None else np.asarray(valid, float),
        "length": np.full((n, 1), size[0]), "width": np.full((n, 1), size[1]), "height": np.full((n, 1), size[2]),
    }


def scenario_dict(n=60, dt=0.1):
    ts = np.arange(n) * dt
    x = np.linspace(-30, 30, n)
    lane_x = np.linspace(-60, 60, 13)
    return {
        "id": "tiny", "version": "test", "length": n,
        "metadata": {"dataset": "synthetic", "scenario_id": "tiny-1", "map": "town", "sdc_id": "ego", "ts": ts,
                     "sample_rate": dt},
        "tracks": {
            "ego": {"type": "VEHICLE", "metadata": {"type": "vehicle.car"},
                    "state": _state(n, np.stack([x, np.zeros(n)], 1), size=(1.73, 4.08, 1.56))},
            "car1": {"type": "VEHICLE", "metadata": {"type": "vehicle.bus.rigid"},
                     "state": _state(n, np.stack([x - 20, np.zeros(n)], 1), size=(11.0, 2.9, 3.5))},
            "ped": {"type": "PEDESTRIAN", "metadata": {}, "state": _state(n, np.stack([np.zeros(n), np.full(n, 8.0)], 1),
                                                                           size=(0.7, 0.7, 1.8))},
            "cone": {"type": "TRAFFIC_CONE", "metadata": {}, "state": _state(n, np.tile([[5.0, 4.0]], (n, 1)),
                                                                              size=(0.4, 0.4, 0.8))},
            "ghost": {"type": "VEHICLE", "metadata": {}, "state": _state(n, np.zeros((n, 2)), valid=np.zeros(n))},
            "ufo": {"type": "UFO", "metadata": {}, "state": _state(n, np.zeros((n, 2)))},
        },
        "dynamic_map_states": {},
        "map_features": {
            "lane_a": {"type": "LANE_SURFACE_STREET", "polyline": np.stack([lane_x, np.zeros(13), np.zeros(13)], 1),
                       "polygon": np.array([[-60, -1.75], [60, -1.75], [60, 1.75], [-60, 1.75]])},
            "line_1": {"type": "ROAD_LINE_SOLID_SINGLE_WHITE", "polyline": np.stack([lane_x, np.full(13, -1.75)], 1)},
            "edge_1": {"type": "ROAD_EDGE_BOUNDARY", "polyline": [(x_, 1.75, 0.0) for x_ in lane_x]},
            "cw": {"type": "CROSSWALK", "polygon": np.array([[40.0, -3], [44, -3], [44, 3], [40, 3]])},
            "bump": {"type": "SPEED_BUMP", "polygon": np.zeros((4, 2))},
        },
    }


def write_pkl(path: Path, obj, protocol=pickle.HIGHEST_PROTOCOL) -> Path:
    with open(path, "wb") as f:
        pickle.dump(obj, f, protocol=protocol)
    return path
