"""``SuiteMeta``: the host-side table of a packed suite, one row per scenario.

No JAX here: ``drivee2e suite info`` reads it from the packed cache's JSON
sidecar (``scenario.cache``) without importing JAX. ``scenario.batch``
re-exports it beside ``PackedBatch``, which pairs it with the arrays.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["META_STR", "META_NUM", "META_2D", "SuiteMeta"]

META_STR = ("scenario_id", "split", "intersection_id", "map_id", "behavior", "weather", "time_of_day")
META_NUM = {"ego_track_id": np.int64, "index": np.int64, "num_agents": np.int32,
             "num_steps": np.int32, "dt": np.float64}
META_2D = {"route_source": np.float64, "route_destination": np.float64, "stop_line_group": np.int32,
           "origin": np.float64}


@dataclass(frozen=True)
class SuiteMeta:
    """Host-side columnar table, one row per packed scenario (row i <-> batch row i).

    1-D columns (length B): ``scenario_id, split, intersection_id, map_id,
    behavior, weather, time_of_day`` (numpy str), ``ego_track_id`` and
    ``index`` (int64; ``index`` equals ``Scenario.index``: the row in the
    suite's meta table), ``num_agents``, ``num_steps`` (int32), ``dt``
    (float64, the record's exact log step).

    2-D columns kept so that :func:`unpack` can rebuild the records:
    ``route_source``, ``route_destination`` (B, 2) float64 and
    ``stop_line_group`` (B, S) int32 (signal group of each stop line, -1 none).

    ``origin`` (B, 2) float64: the world (x, y) of the row's local frame, m
    (``scenario.origin.map_origin`` of its map). Every position in the packed
    arrays, and so in the simulator's state, observations and logs, is local:
    world = local + origin. ``route_source`` / ``route_destination`` are world.
    """

    scenario_id: np.ndarray
    split: np.ndarray
    intersection_id: np.ndarray
    map_id: np.ndarray
    behavior: np.ndarray
    weather: np.ndarray
    time_of_day: np.ndarray
    ego_track_id: np.ndarray
    index: np.ndarray
    num_agents: np.ndarray
    num_steps: np.ndarray
    dt: np.ndarray
    route_source: np.ndarray
    route_destination: np.ndarray
    stop_line_group: np.ndarray
    origin: np.ndarray

    def __len__(self) -> int:
        return len(self.scenario_id)

    def columns(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def select(self, rows: Sequence[int] | np.ndarray) -> SuiteMeta:
        rows = np.asarray(rows)
        return SuiteMeta(**{k: v[rows] for k, v in self.columns().items()})

    take = select  # numpy-style alias

    def rows(self) -> list[dict[str, Any]]:
        """One plain dict per row with the 1-D columns (Python scalars)."""
        cols = {k: getattr(self, k).tolist() for k in (*META_STR, *META_NUM)}
        return [dict(zip(cols, vals)) for vals in zip(*cols.values())]

    to_dicts = rows

    def count(self, column: str) -> dict[str, int]:
        """value -> number of rows, in order of first appearance."""
        values, first, counts = np.unique(getattr(self, column), return_index=True, return_counts=True)
        order = np.argsort(first)
        return {str(values[i]): int(counts[i]) for i in order}

    def to_json(self) -> dict[str, list]:
        return {k: v.tolist() for k, v in self.columns().items()}

    @classmethod
    def from_json(cls, data: dict[str, list]) -> SuiteMeta:
        cols = {k: np.asarray(data[k], dtype=str) for k in META_STR}
        cols.update({k: np.asarray(data[k], dtype=t) for k, t in {**META_NUM, **META_2D}.items()})
        n = len(cols["scenario_id"])
        for k, v in cols.items():
            if len(v) != n:
                raise ValueError(f"SuiteMeta.{k}: {len(v)} rows, expected {n}")
        for k in ("route_source", "route_destination", "origin"):
            cols[k] = cols[k].reshape(n, 2)
        cols["stop_line_group"] = cols["stop_line_group"].reshape(n, -1)
        return cls(**cols)
