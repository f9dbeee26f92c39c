"""Pictures of the sensors for one twin15 scenario (host-side, matplotlib).

    python experiments/sensors/pictures.py [--scenario 0] [--t 5.0] --out docs/img/sensors_twin15.png

Left to right: the top-down scene (map, agents at time t, ego), the BEV the
policy gets (channels coloured), the LiDAR point cloud (ego frame, top view,
coloured by hit class), and the front camera's semantic image.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", type=int, default=0, help="row in twin15's val split")
    ap.add_argument("--t", type=float, default=5.0, help="time, s")
    ap.add_argument("--out", type=Path, default=Path("docs/img/sensors_twin15.png"))
    args = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from drivee2e_jax import replay
    from drivee2e_jax.observe import raycast
    from drivee2e_jax.observe.bev import BevConfig, render_bev
    from drivee2e_jax.observe.camera import CameraRigConfig, camera_images
    from drivee2e_jax.observe.lidar import LidarConfig, lidar_scan
    from drivee2e_jax.observe.raster import rasterize_maps
    from drivee2e_jax.scenario import load_suite

    suite = load_suite("twin15")
    packed = suite.pack("val").select([args.scenario])
    mid = str(packed.meta.map_id[0])
    table = rasterize_maps({mid: suite.maps[mid]})
    scn = jax.tree_util.tree_map(lambda a: jnp.asarray(a[0]), packed.scenario)
    tr = scn.tracks
    i = int(scn.ego_index)
    k = int(round(args.t / float(scn.dt_log)))
    ego_xy, ego_yaw = tr.xy[i, k], tr.yaw[i, k]
    agents = replay.agents_at(tr, jnp.float32(args.t), scn.dt_log)
    agents = agents.replace(valid=agents.valid & (jnp.arange(tr.xy.shape[0]) != i))
    signals = replay.signals_at(scn.signals, jnp.float32(args.t), scn.dt_log)
    cfg = BevConfig()
    bev = np.asarray(render_bev(ego_xy=ego_xy, ego_yaw=ego_yaw, ego_lw=tr.size[i, :2], agents_xy=agents.xy,
                                agents_yaw=agents.yaw, agents_size=tr.size, agents_category=tr.category,
                                agents_valid=agents.valid, stop_state=signals, route_xy=scn.route.xy,
                                route_valid=scn.route.valid, table=table, map_index=jnp.int32(0), cfg=cfg))
    scene = raycast.select_scene(ego_xy, agents, tr.size, tr.category, scn.map.obstacles, scn.map.obstacle_height,
                                 exclude=i)
    scan = lidar_scan(scene, ego_xy, ego_yaw, LidarConfig())
    cams = camera_images(scene, ego_xy, ego_yaw, CameraRigConfig())

    fig, ax = plt.subplots(1, 4, figsize=(22, 5.8))
    # 1. top-down scene
    m = suite.maps[mid]
    for poly in m.drivable_areas:
        ax[0].fill(poly[:, 0], poly[:, 1], color="0.9")
    for b in m.boundaries:
        ax[0].plot(b.points[:, 0], b.points[:, 1], color="0.5", lw=0.6)
    for o in m.obstacles:
        ax[0].fill(o.polygon[:, 0], o.polygon[:, 1], color="tab:brown", alpha=0.6)
    xy, yaw, size, ok = (np.asarray(a) for a in (agents.xy, agents.yaw, tr.size, agents.valid))
    for a in np.flatnonzero(ok):
        _box(ax[0], xy[a], yaw[a], size[a], "tab:blue")
    _box(ax[0], np.asarray(ego_xy), float(ego_yaw), np.asarray(tr.size[i]), "tab:red")
    ax[0].plot(np.asarray(scn.route.xy)[np.asarray(scn.route.valid), 0],
               np.asarray(scn.route.xy)[np.asarray(scn.route.valid), 1], "r--", lw=0.8)
    e = np.asarray(ego_xy)
    ax[0].set_xlim(e[0] - 50, e[0] + 50)
    ax[0].set_ylim(e[1] - 50, e[1] + 50)
    ax[0].set_aspect("equal")
    ax[0].set_title(f"scene {packed.meta.scenario_id[0]} at t = {args.t:.1f} s (ego red)")
    # 2. BEV, channels coloured (later channels on top)
    colours = plt.get_cmap("tab20")(np.arange(len(cfg.channel_names)))[:, :3]
    img = np.ones(bev.shape[:2] + (3,))
    for c in range(bev.shape[-1]):
        img[bev[..., c] > 0.5] = colours[c]
    ax[1].imshow(img, interpolation="nearest")
    ax[1].set_title(f"BEV {cfg.height}x{cfg.width} @ {cfg.resolution} m/px (ego drives up)")
    handles = [plt.Rectangle((0, 0), 1, 1, color=colours[c]) for c in range(len(cfg.channel_names))]
    ax[1].legend(handles, cfg.channel_names, fontsize=6, loc="lower left", ncol=2)
    # 3. LiDAR points, ego frame, top view
    pts, valid, cls = np.asarray(scan.points), np.asarray(scan.valid), np.asarray(scan.hit_class).reshape(-1)
    sc = ax[2].scatter(pts[valid, 0], pts[valid, 1], c=cls[valid], s=0.5, cmap="tab10", vmin=0, vmax=10)
    ax[2].set_aspect("equal")
    ax[2].set_xlim(-60, 60)
    ax[2].set_ylim(-60, 60)
    ax[2].set_title(f"LiDAR {int(valid.sum())} returns, ego frame (x fwd), by hit class")
    fig.colorbar(sc, ax=ax[2], fraction=0.04)
    # 4. front camera semantic
    sem = np.asarray(cams.semantic)[0]
    ax[3].imshow(sem, cmap="tab10", vmin=0, vmax=10, interpolation="nearest")
    ax[3].set_title("front camera: semantic (0 sky, 1 ground, 2 static, 3+ agents)")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90)
    print(args.out)
    return 0


def _box(ax, xy, yaw, size, colour):
    c, s = np.cos(yaw), np.sin(yaw)
    hl, hw = size[0] / 2, size[1] / 2
    corners = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw], [hl, hw]])
    pts = xy + corners @ np.array([[c, s], [-s, c]])
    ax.fill(pts[:, 0], pts[:, 1], color=colour, alpha=0.8)


if __name__ == "__main__":
    raise SystemExit(main())
