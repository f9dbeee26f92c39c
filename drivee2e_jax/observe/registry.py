"""The sensor registry: every ``Sensor`` by name (``observe.sensor_api``).

The rollout (``observe.sensors``: ``SensorConfig``, ``render``), the episode
traces, the HTML player and the MCAP export look sensors up here. Built-in
sensors are listed in ``BUILTIN``: adding one is a module with a
``SensorBase`` subclass and a ``SENSOR`` instance, plus one entry below
(docs/sensors.md, "Adding a sensor"). ``register`` adds a sensor at run time
(an out-of-tree plug-in, a test's toy sensor); ``unregister`` removes it.
"""

from __future__ import annotations

from drivee2e_jax.observe import bev, lidar
from drivee2e_jax.observe.sensor_api import DISPLAYS, Sensor

#: The built-in sensors, in the order they render and are shown.
BUILTIN: tuple[Sensor, ...] = (
    bev.SENSOR,
    lidar.SENSOR,
)

#: Names with their own ``types.Observation`` slot (``obs.bev``, ``obs.lidar``)
#: and their own ``eval.traces.EpisodeTrace`` fields; every other sensor's
#: output goes to ``obs.sensors[name]`` / ``EpisodeTrace.sensors[name]``.
SLOTTED = ("bev", "lidar")

#: Names a sensor may not take: other outputs of an episode (MCAP topics
#: ``/<scenario>/<name>``, the ``Observation.sensors`` slot).
RESERVED = ("tf", "scene", "map", "metrics", "infractions", "sensors")

_SENSORS: dict[str, Sensor] = {}


def register(sensor: Sensor, *, replace: bool = False) -> Sensor:
    """Add ``sensor`` under ``sensor.name``; returns it. Raises ValueError on
    a name taken (unless ``replace``), an empty or reserved name, or an
    unknown display."""
    name = getattr(sensor, "name", "")
    if not name or not isinstance(name, str) or "/" in name or "@" in name:
        raise ValueError(f"sensor name must be a non-empty string without '/' or '@', got {name!r}")
    if name in RESERVED:
        raise ValueError(f"sensor name {name!r} is reserved ({', '.join(RESERVED)})")
    if getattr(sensor, "display", None) not in DISPLAYS:
        raise ValueError(f"sensor {name!r}: display must be one of {', '.join(DISPLAYS)}, "
                         f"got {getattr(sensor, 'display', None)!r}")
    if name in _SENSORS and not replace:
        raise ValueError(f"sensor {name!r} is already registered ({_SENSORS[name]!r})")
    _SENSORS[name] = sensor
    return sensor


def unregister(name: str) -> None:
    """Remove a sensor added with ``register`` (a built-in cannot be removed)."""
    if name in {s.name for s in BUILTIN}:
        raise ValueError(f"sensor {name!r} is built in")
    _SENSORS.pop(name, None)


def get(name: str) -> Sensor:
    """The sensor called ``name``; ValueError listing the known ones."""
    try:
        return _SENSORS[name]
    except KeyError:
        raise ValueError(f"unknown sensor {name!r} (expected some of {', '.join(_SENSORS)})") from None


def names() -> tuple[str, ...]:
    """Every registered sensor name, built-ins first, in registration order."""
    return tuple(_SENSORS)


def shown() -> tuple[str, ...]:
    """Names of the sensors that can be drawn (``display`` other than "none")."""
    return tuple(n for n, s in _SENSORS.items() if s.display != "none")


for _s in BUILTIN:
    register(_s)
