"""Top-down picture of an imported scene: map + agents at one time (host side).

    python experiments/importers/plot_scene.py SUITE_DIR [--scenario ID] [--t SECONDS]
        [--map MAP_ID] [--tracks-all] --out docs/img/imported_<name>.png
    python experiments/importers/plot_scene.py --lanelet2 MAP.osm [--csv TRACKS.csv ...]
        [--t SECONDS] --out PNG      # a Lanelet2 map with raw drone tracks (no suite needed)

Draws the drivable area (grey), lane centrelines (blue; connectors orange)
with arrows in driving direction, boundaries by marking, crosswalks (hatched),
stop lines (red: signalised, black: not), agent boxes at time ``--t`` (ego
green, vehicles blue, pedestrians/cyclists magenta), and with ``--tracks-all``
every track's full path as a thin line, to check that lanes lie where the
tracks drive.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from drivee2e_jax.records import MapRecord, ScenarioRecord  # noqa: E402
from drivee2e_jax.scenario.schema import read_suite  # noqa: E402

_MARK_STYLE = {"road_edge": ("k", "-", 1.6), "solid": ("0.3", "-", 0.9), "double_solid": ("y", "-", 1.2),
               "dashed": ("0.45", "--", 0.8)}
_SMALL = ("pedestrian", "cyclist")


def draw_map(ax, m: MapRecord) -> None:
    from matplotlib.patches import Polygon

    for poly in m.drivable_areas:
        ax.add_patch(Polygon(poly, closed=True, fc="0.9", ec="none", zorder=0))
    for poly in m.crosswalks:
        ax.add_patch(Polygon(poly, closed=True, fc="none", ec="tab:purple", hatch="///", lw=0.6, zorder=1))
    for b in m.boundaries:
        c, ls, lw = _MARK_STYLE.get(b.marking, ("0.6", ":", 0.6))
        ax.plot(b.points[:, 0], b.points[:, 1], color=c, ls=ls, lw=lw, zorder=2)
    for ln in m.lanes:
        c = ln.centerline
        col = "tab:orange" if ln.type == "connector" else "tab:blue"
        ax.plot(c[:, 0], c[:, 1], color=col, lw=0.6, alpha=0.8, zorder=3)
        k = len(c) // 2
        k = min(max(k, 0), len(c) - 2)
        d = c[k + 1] - c[k]
        ax.annotate("", xy=c[k] + d * 0.9, xytext=c[k], arrowprops=dict(arrowstyle="->", color=col, lw=0.8), zorder=3)
    for s in m.stop_lines:
        ax.plot(s.points[:, 0], s.points[:, 1], color="red" if s.signal_group >= 0 else "k", lw=2.0, zorder=4)


def draw_agents(ax, s: ScenarioRecord, t: float, tracks_all: bool) -> None:
    from matplotlib.patches import Polygon

    for tr in s.tracks:
        ego = tr.track_id == s.ego_track_id
        col = "tab:green" if ego else ("m" if tr.category in _SMALL else "tab:blue")
        if tracks_all or ego:
            ax.plot(tr.xy[:, 0], tr.xy[:, 1], color=col, lw=1.2 if ego else 0.4, alpha=0.9 if ego else 0.5, zorder=5)
        k = np.flatnonzero(np.abs(tr.t - t) < s.dt / 2)
        if not len(k):
            continue
        (x, y), yaw = tr.xy[k[0]], tr.yaw[k[0]]
        length, width = max(tr.size[0], 0.5), max(tr.size[1], 0.5)
        c, sn = np.cos(yaw), np.sin(yaw)
        corners = np.array([[length, width], [length, -width], [-length, -width], [-length, width]]) / 2
        pts = corners @ np.array([[c, sn], [-sn, c]]) + [x, y]
        ax.add_patch(Polygon(pts, closed=True, fc=col, ec="k", lw=0.4, alpha=0.85, zorder=6))
    r = s.route.waypoints
    ax.plot(r[:, 0], r[:, 1], color="tab:green", ls=":", lw=1.5, zorder=5)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("suite", type=Path, nargs="?")
    ap.add_argument("--lanelet2", type=Path, default=None, help="draw this Lanelet2 .osm map instead of a suite")
    ap.add_argument("--csv", type=Path, action="append", default=[], help="track CSV to draw on --lanelet2")
    ap.add_argument("--scenario", default=None, help="scenario id (default: the first)")
    ap.add_argument("--map", default=None, help="draw this map alone (maps-only suites)")
    ap.add_argument("--t", type=float, default=None, help="time, s (default: middle of the log)")
    ap.add_argument("--tracks-all", action="store_true")
    ap.add_argument("--title", default=None)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    fig, ax = plt.subplots(figsize=(9, 9))
    if a.lanelet2 is not None:
        title = draw_lanelet2(ax, a.lanelet2, a.csv, a.t, a.title)
        return _save(fig, ax, title, a.out)
    if a.suite is None:
        ap.error("give a suite folder or --lanelet2 MAP.osm")
    suite = read_suite(a.suite)
    if a.map is not None or not suite.scenarios:
        m = suite.maps[a.map or sorted(suite.maps)[0]]
        draw_map(ax, m)
        title = a.title or f"{suite.name}: map {m.map_id}"
    else:
        s = next((x for x in suite.scenarios if x.scenario_id == a.scenario), suite.scenarios[0])
        draw_map(ax, suite.maps[s.map_id])
        t = a.t if a.t is not None else round((s.num_steps - 1) * s.dt / 2 / s.dt) * s.dt
        draw_agents(ax, s, t, a.tracks_all)
        title = a.title or f"{suite.name}: {s.scenario_id} ({s.behavior}) at t = {t:.1f} s"
    _save(fig, ax, title, a.out)


def draw_lanelet2(ax, osm: Path, csvs: list[Path], t: float | None, title: str | None) -> str:
    """A Lanelet2 map with every raw track of ``csvs`` as a thin line and a dot at time ``t``."""
    from drivee2e_jax.scenario.importers.lanelet2 import load_map
    from drivee2e_jax.scenario.importers.lanelet2_csv import read_tracks

    m, _ = load_map(osm, osm.stem)
    draw_map(ax, m)
    n = 0
    for p in csvs:
        raws, _, _ = read_tracks(p, 0.0)
        for r in raws:
            col = "m" if r.category in _SMALL else "tab:blue"
            ax.plot(r.xy[:, 0], r.xy[:, 1], color=col, lw=0.4, alpha=0.5, zorder=5)
            if t is not None:
                k = np.flatnonzero(np.abs(r.t - t) < 0.06)
                if len(k):
                    ax.plot(*r.xy[k[0]], "o", color=col, ms=4, mec="k", zorder=6)
            n += 1
    return title or f"{osm.name}: {n} raw tracks" + (f", dots at t = {t:.1f} s" if t is not None else "")


def _save(fig, ax, title: str, out: Path) -> None:
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
