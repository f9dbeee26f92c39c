"""The published seam of the sensors: ``Sensor``, ``SensorContext``, ``SensorAssets``.

A sensor is an object with a ``name`` and a ``display`` kind that renders ONE
scenario at ONE instant from ONE context pytree (``SensorContext``: the
scenario, the ego, the agents and signals at that instant, the host-built
assets, a PRNG key) and a static config of its own::

    out = sensor.render(ctx, cfg)   # in-graph, jittable; callers vmap

The registry (``observe.registry``) lists the sensors by name; the rollout
(``observe.sensors.render``), the episode traces (``eval.traces``), the HTML
player (``viz``) and the MCAP export (``io.mcap_export``) all go through it,
so a new sensor is one file (a ``SensorBase`` subclass) plus one entry in
``observe.registry`` (docs/sensors.md, "Adding a sensor").

How a sensor is shown (``display``):

* ``"image"``: ``sensor.image(frame, cfg)`` -> (H, W, 3) uint8 picture
  (a PNG pane in the player, a ``foxglove.CompressedImage`` topic);
* ``"pointcloud"``: ``sensor.points(frame, cfg)`` -> ((N, 3) float32 x, y, z
  in the ego frame (origin at the box centre on the ground, x forward, y
  left, z up), m; (N,) int hit class (``raycast`` codes)) of the valid points
  (a point pane in the player, a ``foxglove.PointCloud`` topic);
* ``"none"``: traced but not drawn.

``frame`` is one instant of what ``sensor.trace(ctx, cfg)`` returned (host
numpy; by default the same as ``render``).
"""

from __future__ import annotations

import dataclasses
import zlib
from typing import Any, Protocol, runtime_checkable

import jax
import jax.numpy as jnp
from flax import struct

from drivee2e_jax.observe import raycast
from drivee2e_jax.observe.raster import RasterTable
from drivee2e_jax.replay import AgentStates
from drivee2e_jax.types import EgoState, Scenario

Array = jnp.ndarray

#: How a sensor's output can be shown (``Sensor.display``).
DISPLAYS = ("image", "pointcloud", "none")


@struct.dataclass
class SensorAssets:
    """Host-built inputs of the sensors, for one scenario.

    Attributes:
      raster: RasterTable of every map of the batch (shared, broadcast under vmap).
      map_index: () int32 this scenario's row in ``raster`` ((B,) when batched).
    """

    raster: RasterTable
    map_index: jnp.ndarray


@struct.dataclass
class SensorContext:
    """Everything a sensor may read, for one scenario at one instant.

    Attributes:
      scenario: ``types.Scenario`` (unbatched): tracks, map, route, signals.
      ego: ``types.EgoState`` the SIMULATED ego at this instant.
      ego_lw: (2,) float32 ego length and width, m.
      agents: ``replay.AgentStates`` (A,) every logged agent replayed at this
        instant, the ego's own row marked invalid (``sim.Simulator.agents``).
      stop_state: (S,) int32 ``SignalState`` per stop line at this instant.
      route_index: () int32 the ego's progress point on the route, or None
        (the BEV then draws the whole route).
      assets: ``SensorAssets`` (the map rasters) or None when no sensor needs them.
      key: PRNG key of this sensor's noise (``observe.sensors.render`` folds
        the sensor's name into the observation key), or None.
      scene: static ``raycast.SceneConfig``: which agents / obstacles the
        ray-cast sensors consider (``ray_scene``).
    """

    scenario: Scenario
    ego: EgoState
    ego_lw: Array
    agents: AgentStates
    stop_state: Array
    route_index: Array | None = None
    assets: SensorAssets | None = None
    key: Array | None = None
    scene: raycast.SceneConfig = struct.field(pytree_node=False, default=raycast.SceneConfig())

    @property
    def ego_row(self) -> Array:
        """() int32 the ego's own row in the tracks."""
        return self.scenario.ego_index

    @property
    def size(self) -> Array:
        """(A, 3) float32 agent length, width, height, m."""
        return self.scenario.tracks.size

    @property
    def category(self) -> Array:
        """(A,) int32 ``types.Category`` per agent."""
        return self.scenario.tracks.category

    def ray_scene(self) -> raycast.RayScene:
        """The nearest agents (the ego's row excluded) and obstacles for the
        ray-cast sensors (``raycast.select_scene`` with ``scene``)."""
        m = self.scenario.map
        return raycast.select_scene(self.ego.xy, self.agents, self.size, self.category, m.obstacles,
                                    m.obstacle_height, self.scene, exclude=self.ego_row)

    def for_sensor(self, name: str) -> SensorContext:
        """This context with ``key`` folded with ``name`` (each sensor draws its
        own noise; a sensor that draws none costs nothing under jit)."""
        if self.key is None:
            return self
        return self.replace(key=jax.random.fold_in(self.key, zlib.crc32(name.encode()) & 0x7FFFFFFF))


@runtime_checkable
class Sensor(Protocol):
    """What the registry holds (see the module docstring).

    Attributes:
      name: the registry key; the ``Observation`` slot (``obs.<name>`` for
        the built-in ``bev`` / ``lidar``, ``obs.sensors[name]`` otherwise),
        the trace key, the MCAP topic ``/<scenario>/<name>``, the player pane.
      display: one of ``DISPLAYS``.
      needs_raster: ``observe.sensors.build_assets`` must rasterise the maps.
    """

    name: str
    display: str
    needs_raster: bool

    def default_config(self) -> Any:
        """The config used when a policy lists the sensor in ``required_sensors``
        (frozen, hashable: it is static under jit)."""
        ...

    def render(self, ctx: SensorContext, cfg) -> Any:
        """The observation value (an array or pytree) of one scenario at one instant."""
        ...

    def trace(self, ctx: SensorContext, cfg) -> Any:
        """What an episode trace keeps per instant (in-graph)."""
        ...

    def image(self, frame, cfg):
        """(H, W, 3) uint8 picture of one traced frame (``display == "image"``)."""
        ...

    def points(self, frame, cfg):
        """((N, 3) float32 ego-frame points, m; (N,) int classes) of one traced
        frame (``display == "pointcloud"``)."""
        ...


class SensorBase:
    """Defaults for a ``Sensor``: no raster, shown as nothing, traced as rendered.

    Subclass it, set ``name`` / ``display``, define ``default_config`` and
    ``render`` (and ``image`` or ``points`` for a displayed sensor)."""

    name: str = ""
    display: str = "none"
    needs_raster: bool = False

    def default_config(self) -> Any:
        raise NotImplementedError(f"sensor {self.name!r}: no default_config")

    def render(self, ctx: SensorContext, cfg) -> Any:
        raise NotImplementedError(f"sensor {self.name!r}: no render")

    def trace(self, ctx: SensorContext, cfg) -> Any:
        return self.render(ctx, cfg)

    def image(self, frame, cfg):
        raise NotImplementedError(f"sensor {self.name!r} (display {self.display!r}) draws no image")

    def points(self, frame, cfg):
        raise NotImplementedError(f"sensor {self.name!r} (display {self.display!r}) has no point cloud")

    def __repr__(self) -> str:
        return f"<sensor {self.name!r} ({self.display})>"


@dataclasses.dataclass
class SensorFrames:
    """Host-side frames of one sensor over an episode trace.

    Attributes:
      config: the sensor's config the frames were rendered with.
      frames: ``Sensor.trace`` output stacked over the T traced instants
        (numpy; every leaf has leading axis T).
    """

    config: Any
    frames: Any

    def frame(self, k: int):
        """Instant ``k`` of ``frames``."""
        return jax.tree_util.tree_map(lambda a: a[k], self.frames)
