"""OpenDRIVE importer: every plan-view geometry against independent closed
forms / quadrature, lane widths and offsets, a small junction, and errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, special

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario.importers import opendrive as od
from drivee2e_jax.scenario.importers.common import ImportOptions
from tests.helpers.importer_files import JUNCTION, XODR_HEAD, interaction_csv


def G(kind, length, x=0.0, y=0.0, hdg=0.0, **params):
    return od.Geometry(0.0, x, y, hdg, length, kind, params)


# --------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------


def test_line():
    xy, h = od.eval_geometry(G("line", 10.0, 1.0, 2.0, math.pi / 6), np.array([0.0, 4.0]))
    np.testing.assert_allclose(xy[1], [1 + 4 * math.cos(math.pi / 6), 2 + 4 * math.sin(math.pi / 6)], atol=1e-12)
    np.testing.assert_allclose(h, math.pi / 6)


@pytest.mark.parametrize("k", [0.05, -0.1])
def test_arc_chord_and_radius(k):
    g = G("arc", 30.0, 3.0, -1.0, 0.4, curvature=k)
    ds = np.array([0.0, 7.0, 25.0])
    xy, h = od.eval_geometry(g, ds)
    # the centre lies 1/k to the left of the start; every point is 1/|k| from it
    centre = np.array([3.0, -1.0]) + np.array([-math.sin(0.4), math.cos(0.4)]) / k
    np.testing.assert_allclose(np.linalg.norm(xy - centre, axis=1), 1 / abs(k), atol=1e-9)
    # chord length of an arc of length s: 2 sin(|k| s / 2) / |k|
    chord = np.linalg.norm(xy - xy[0], axis=1)
    np.testing.assert_allclose(chord, 2 * np.sin(abs(k) * ds / 2) / abs(k), atol=1e-9)
    np.testing.assert_allclose(h, 0.4 + k * ds, atol=1e-12)


@pytest.mark.parametrize("rate", [0.002, -0.01])
def test_spiral_from_zero_curvature_matches_fresnel(rate):
    length = 40.0
    g = G("spiral", length, curvStart=0.0, curvEnd=rate * length)
    ds = np.array([0.0, 13.3, 27.1, 40.0])
    xy, h = od.eval_geometry(g, ds)
    a = math.sqrt(math.pi / abs(rate))
    S, C = special.fresnel(ds / a)
    np.testing.assert_allclose(xy[:, 0], a * C, atol=1e-6)
    np.testing.assert_allclose(xy[:, 1], math.copysign(1.0, rate) * a * S, atol=1e-6)
    np.testing.assert_allclose(h, rate * ds**2 / 2, atol=1e-12)


def test_spiral_general_matches_quadrature():
    k0, k1, length, hdg = 0.03, -0.02, 35.0, 1.1
    g = G("spiral", length, 5.0, 6.0, hdg, curvStart=k0, curvEnd=k1)
    c = (k1 - k0) / length
    s = 21.7
    th = lambda t: hdg + k0 * t + c * t * t / 2  # noqa: E731
    ex = 5.0 + integrate.quad(lambda t: math.cos(th(t)), 0, s, epsabs=1e-12)[0]
    ey = 6.0 + integrate.quad(lambda t: math.sin(th(t)), 0, s, epsabs=1e-12)[0]
    xy, _ = od.eval_geometry(g, np.array([s]))
    np.testing.assert_allclose(xy[0], [ex, ey], atol=1e-7)


def _arc_len(du, dv, p):
    return integrate.quad(lambda q: math.hypot(du(q), dv(q)), 0.0, p, epsabs=1e-12)[0]


def test_poly3_point_at_true_arc_length():
    a, b, c, d = 0.5, 0.1, 0.01, -0.0002
    v = lambda u: a + b * u + c * u * u + d * u**3  # noqa: E731
    dv = lambda u: b + 2 * c * u + 3 * d * u * u  # noqa: E731
    u_star = 17.0
    s_star = _arc_len(lambda u: 1.0, dv, u_star)
    hdg = -0.7
    g = G("poly3", 30.0, 2.0, 1.0, hdg, a=a, b=b, c=c, d=d)
    xy, h = od.eval_geometry(g, np.array([s_star]))
    expect = np.array([2.0 + u_star * math.cos(hdg) - v(u_star) * math.sin(hdg),
                       1.0 + u_star * math.sin(hdg) + v(u_star) * math.cos(hdg)])
    np.testing.assert_allclose(xy[0], expect, atol=2e-4)
    np.testing.assert_allclose(h[0], hdg + math.atan(dv(u_star)), atol=1e-4)


@pytest.mark.parametrize("prange", ["normalized", "arcLength"])
def test_param_poly3_both_ranges(prange):
    L = 25.0
    p_end = 1.0 if prange == "normalized" else L
    # u(p), v(p): a gentle S-curve written per unit p
    cu = dict(aU=0.0, bU=24.0 / p_end, cU=1.0 / p_end**2, dU=-0.5 / p_end**3)
    cv = dict(aV=0.0, bV=0.0, cV=6.0 / p_end**2, dV=-4.0 / p_end**3)
    u = lambda p: cu["bU"] * p + cu["cU"] * p * p + cu["dU"] * p**3  # noqa: E731
    v = lambda p: cv["cV"] * p * p + cv["dV"] * p**3  # noqa: E731
    du = lambda p: cu["bU"] + 2 * cu["cU"] * p + 3 * cu["dU"] * p * p  # noqa: E731
    dv = lambda p: 2 * cv["cV"] * p + 3 * cv["dV"] * p * p  # noqa: E731
    p_star = 0.6 * p_end
    s_star = _arc_len(du, dv, p_star)
    # normalized: length is the curve's arc length; arcLength: length is the p range itself
    length = _arc_len(du, dv, p_end) if prange == "normalized" else L
    g = G("paramPoly3", length, 0.0, 0.0, 0.3, pRange=prange, **cu, **cv)
    xy, h = od.eval_geometry(g, np.array([s_star, g.length]))
    c, s = math.cos(0.3), math.sin(0.3)
    np.testing.assert_allclose(xy[0], [u(p_star) * c - v(p_star) * s, u(p_star) * s + v(p_star) * c], atol=2e-4)
    if prange == "normalized":
        np.testing.assert_allclose(xy[1], [u(1) * c - v(1) * s, u(1) * s + v(1) * c], atol=2e-4)
    np.testing.assert_allclose(h[0], 0.3 + math.atan2(dv(p_star), du(p_star)), atol=1e-4)


@settings(deadline=None, max_examples=30)
@given(k0=st.floats(-0.08, 0.08), k1=st.floats(-0.08, 0.08), length=st.floats(2.0, 60.0),
       hdg=st.floats(-3.0, 3.0))
def test_spiral_is_arc_length_parametrised(k0, k1, length, hdg):
    g = G("spiral", length, 0.0, 0.0, hdg, curvStart=k0, curvEnd=k1)
    ds = np.linspace(0.0, length, 401)
    xy, h = od.eval_geometry(g, ds)
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    np.testing.assert_allclose(steps, length / 400, rtol=1e-3)  # chords of short arcs ~ arc length
    d = np.diff(xy, axis=0)
    mid_h = (h[1:] + h[:-1]) / 2
    np.testing.assert_allclose(np.cos(mid_h) * d[:, 0] + np.sin(mid_h) * d[:, 1], steps, rtol=1e-3)


# --------------------------------------------------------------------------
# Lanes and junctions
# --------------------------------------------------------------------------

_HEAD = XODR_HEAD

STRAIGHT = _HEAD + """
<road id="7" length="40" junction="-1">
  <planView><geometry s="0" x="0" y="0" hdg="0" length="40"><line/></geometry></planView>
  <lanes>
    <laneOffset s="0" a="0.5" b="0" c="0" d="0"/>
    <laneSection s="0">
      <left><lane id="1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/>
        <roadMark sOffset="0" type="solid"/></lane>
        <lane id="2" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane></left>
      <center><lane id="0" type="none"><roadMark sOffset="0" type="broken"/></lane></center>
      <right><lane id="-1" type="driving"><width sOffset="0" a="3.0" b="0.01" c="0" d="0"/>
        <roadMark sOffset="0" type="broken"/></lane>
        <lane id="-2" type="driving"><width sOffset="0" a="3.0" b="0" c="0" d="0"/></lane></right>
    </laneSection>
  </lanes>
</road></OpenDRIVE>
"""

# JUNCTION (two roads joined by a connecting arc) is in tests/helpers/importer_files.py,
# shared with the CLI import tests.


def _write(tmp_path: Path, text: str, name: str = "m.xodr") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_lane_widths_offsets_directions_and_marks(tmp_path):
    m, notes = od.read_map(_write(tmp_path, STRAIGHT))
    lanes = {ln.id: ln for ln in m.lanes}
    assert set(lanes) == {49, 48, 51}  # -1, -2, +1; the sidewalk is not a lane
    assert any("non-traffic" in n for n in notes)
    r1, r2, l1 = lanes[49], lanes[48], lanes[51]
    # lane -1 at s: inner border 0.5, width 3 + 0.01 s -> centre 0.5 - (3 + 0.01 s) / 2, driving +x
    for s in (0.0, 20.0, 39.0):
        y = np.interp(s, r1.centerline[:, 0], r1.centerline[:, 1])
        assert y == pytest.approx(0.5 - (3.0 + 0.01 * s) / 2, abs=2e-3)
        y2 = np.interp(s, r2.centerline[:, 0], r2.centerline[:, 1])
        assert y2 == pytest.approx(0.5 - (3.0 + 0.01 * s) - 1.5, abs=2e-3)
    assert r1.centerline[-1, 0] > r1.centerline[0, 0]
    assert l1.centerline[-1, 0] < l1.centerline[0, 0]  # left lane runs against s
    np.testing.assert_allclose(l1.centerline[:, 1], 0.5 + 1.75, atol=1e-6)
    assert r1.width == pytest.approx(3.0 + 0.01 * 20, abs=0.01)
    # marks: lane -1's inner border is the centre mark (broken), its outer its own (broken)
    assert (r1.left_marking, r1.right_marking) == ("dashed", "dashed")
    # lane -2 has no mark and nothing outside: road edge; lane 1: centre broken on its left, own solid outside
    assert r2.right_marking == "road_edge"
    assert (l1.left_marking, l1.right_marking) == ("dashed", "solid")
    assert all(ln.type == "driving" for ln in m.lanes)


def test_junction_connector_and_successors(tmp_path):
    m, _ = od.read_map(_write(tmp_path, JUNCTION))
    lanes = {ln.id: ln for ln in m.lanes}
    # road index 0 lane -1 -> road index 1 (junction) lane -1 -> road index 2 lane -1
    assert lanes[49].successors == [1049]
    assert lanes[1049].type == "connector"
    assert (lanes[1049].left_marking, lanes[1049].right_marking) == ("none", "none")
    assert lanes[1049].successors == [2049]
    assert lanes[49].type == "driving" and lanes[2049].type == "driving"
    c = lanes[1049].centerline
    np.testing.assert_allclose(c[0], [50.0, -1.75], atol=1e-6)
    np.testing.assert_allclose(c[-1], [71.75, 20.0], atol=1e-3)
    # a quarter circle of radius 21.75 about (50, 20)
    np.testing.assert_allclose(np.linalg.norm(c - [50.0, 20.0], axis=1), 21.75, atol=0.06)
    assert m.meta["lane_ids"]["1049"] == "2/0/-1"
    assert m.drivable_areas and m.boundaries


@pytest.mark.parametrize("text, needle", [
    ("<OpenDRIVE><road", "well-formed"),
    ("<Other/>", "<OpenDRIVE> root"),
    (_HEAD + "</OpenDRIVE>", "at least one <road>"),
    (_HEAD + '<road id="4" length="10"><lanes><laneSection s="0"/></lanes></road></OpenDRIVE>', "road id=4: expected at least one <planView>"),
    (_HEAD + '<road id="4" length="10"><planView><geometry s="0" x="0" y="0" hdg="0" length="10"><clothoid/></geometry>'
     '</planView></road></OpenDRIVE>', "road id=4/planView/geometry[0]: expected one of <line>"),
    (_HEAD + '<road id="4" length="10"><planView><geometry s="0" x="0" hdg="0" length="10"><line/></geometry>'
     '</planView></road></OpenDRIVE>', "geometry[0]: expected a numeric 'y' attribute"),
    (_HEAD + '<road id="4" length="10"><planView><geometry s="0" x="0" y="0" hdg="0" length="10">'
     '<paramPoly3 aU="0" bU="1" cU="0" dU="0" aV="0" bV="0" cV="0" dV="0" pRange="weird"/></geometry>'
     '</planView><lanes><laneSection s="0"/></lanes></road></OpenDRIVE>', "expected pRange"),
])
def test_bad_files_give_one_line_errors(tmp_path, text, needle):
    p = _write(tmp_path, text)
    with pytest.raises(DriveE2EError) as e:
        od.read_map(p)
    msg = str(e.value)
    assert str(p) in msg and needle in msg and "\n" not in msg


# --------------------------------------------------------------------------
# load(): map alone, map + INTERACTION tracks
# --------------------------------------------------------------------------


def test_load_map_alone_gives_no_scenario(tmp_path):
    res = od.load([_write(tmp_path, JUNCTION)], ImportOptions())
    assert list(res.maps) == ["m"] and res.scenarios == []
    assert any("map only" in n for n in res.notes)


def test_load_with_interaction_tracks(tmp_path):
    xodr = _write(tmp_path, JUNCTION)
    m, _ = od.read_map(xodr)
    lanes = {ln.id: ln for ln in m.lanes}
    path = np.vstack([lanes[49].centerline, lanes[1049].centerline[1:], lanes[2049].centerline[1:]])
    rec = tmp_path / "rec"
    rec.mkdir()
    interaction_csv(rec / "vehicle_tracks_000.csv", path)
    res = od.load([xodr, rec / "vehicle_tracks_000.csv"], ImportOptions())
    assert len(res.scenarios) == 1, res.skipped
    s = res.scenarios[0]
    assert s.behavior == "LFT" and s.map_id == "m"
    from drivee2e_jax.scenario.importers.common import write_result
    from drivee2e_jax.scenario.schema import validate_suite
    write_result(res, tmp_path / "suite", name="od")
    assert validate_suite(tmp_path / "suite") == []


def test_track_path_alone_finds_the_map_next_to_it(tmp_path):
    xodr = _write(tmp_path, JUNCTION)
    m, _ = od.read_map(xodr)
    lanes = {ln.id: ln for ln in m.lanes}
    rec = tmp_path / "rec"
    rec.mkdir()
    interaction_csv(rec / "vehicle_tracks_000.csv", np.vstack([lanes[49].centerline, lanes[1049].centerline[1:]]))
    res = od.load([rec], ImportOptions())  # the CLI calls load once per path
    assert len(res.scenarios) == 1 and list(res.maps) == ["m"]
    xodr.unlink()
    with pytest.raises(DriveE2EError, match="expected an .xodr map given with it"):
        od.load([rec], ImportOptions())
