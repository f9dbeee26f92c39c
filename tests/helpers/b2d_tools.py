"""Bench2Drive's vendored tools (tests/data/third_party/bench2drive/), imported
without CARLA: ``carla`` and CARLA's ``agents`` route planner (imported at the
tools' top, used only by their map-based parts) are stand-ins."""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path

#: The vendored Bench2Drive tool scripts (their README says where from).
B2D_TOOLS = Path(__file__).resolve().parents[1] / "data" / "third_party" / "bench2drive"


def stand_in_carla(monkeypatch, planner: type = object) -> None:
    """Put stand-ins for ``carla`` (``Location`` -> an (x, y, z) tuple) and
    ``agents.navigation.global_route_planner`` (``GlobalRoutePlanner`` =
    ``planner``) in ``sys.modules`` for the test."""
    carla = types.ModuleType("carla")
    carla.Location = lambda x, y, z: (x, y, z)
    route_planner = types.ModuleType("agents.navigation.global_route_planner")
    route_planner.GlobalRoutePlanner = planner
    for name, mod in (("carla", carla), ("agents", types.ModuleType("agents")),
                      ("agents.navigation", types.ModuleType("agents.navigation")),
                      ("agents.navigation.global_route_planner", route_planner)):
        monkeypatch.setitem(sys.modules, name, mod)


def load_b2d_tool(name: str, monkeypatch, planner: type = object):
    """The vendored tool ``<name>.py`` as a module, imported with the stand-ins."""
    stand_in_carla(monkeypatch, planner)
    spec = importlib.util.spec_from_file_location(f"b2d_{name}", B2D_TOOLS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
