"""Behaviour-label thresholds, shared by the twin15 generator's label checks
(``twin15.labels``, ``twin15.movements``) and the importers' label inference
(``importers.behavior.infer_behavior``), so that a label means the same
whatever made the scenario. Host-side; degrees, metres, seconds, m/s.

``turn_label(turn_deg)`` is the turn label of a total heading change.
"""

from __future__ import annotations

import math

__all__ = [
    "TURN_MIN_DEG", "UTURN_MIN_DEG", "STOP_SPEED_MPS", "STOP_LINE_NEAR_M", "STOP_MIN_S", "STOP_RESUME_M",
    "IPC_AHEAD_M", "COV_AHEAD_M", "COV_MIN_ANGLE", "turn_label",
]

#: A heading change (deg) beyond this is a turn (LFT left, RT right); a map
#: movement too (``twin15.movements.classify``).
TURN_MIN_DEG = 40.0
#: A heading change (deg) beyond this is a U-turn (UT).
UTURN_MIN_DEG = 150.0
#: Below this the ego counts as stopped (STP), m/s.
STOP_SPEED_MPS = 0.1
#: twin15 STP: the ego's front stops within this of its stop line, m.
STOP_LINE_NEAR_M = 3.0
#: Imported STP: stopped at least this long, s, ...
STOP_MIN_S = 1.0
#: ... then driving on at least this far, m.
STOP_RESUME_M = 5.0
#: IPC: the ego within this before (or on) a crossing its path crosses, m.
IPC_AHEAD_M = 25.0
#: Imported COV: the other vehicle passes the crossing point while the ego
#: is within this before it, m ...
COV_AHEAD_M = 25.0
#: ... and the two paths cross at more than this, rad.
COV_MIN_ANGLE = math.radians(30.0)


def turn_label(turn_deg: float, *, left_uturns_only: bool = False) -> str:
    """UT / LFT / RT / STR of a total heading change ``turn_deg`` (deg, + = left).

    ``|turn| > UTURN_MIN_DEG`` is UT; with ``left_uturns_only`` (twin15, whose
    U-turns are all to the left) only ``turn > UTURN_MIN_DEG`` is, and a
    larger right turn stays RT.
    """
    if (turn_deg if left_uturns_only else abs(turn_deg)) > UTURN_MIN_DEG:
        return "UT"
    if turn_deg > TURN_MIN_DEG:
        return "LFT"
    if turn_deg < -TURN_MIN_DEG:
        return "RT"
    return "STR"
