"""Worked cases OL-01 / OL-04 of the open-loop planning metrics
(``drivee2e_jax.metrics.openloop``), from a case dict of ``metric_cases.json``."""

from __future__ import annotations

import numpy as np

from drivee2e_jax.metrics import openloop as olm


def _close(got, want, tol, what):
    got = np.asarray(got, np.float64)
    want = np.asarray(want, np.float64)
    assert got.shape == want.shape, f"{what}: shape {got.shape} != {want.shape}"
    assert np.allclose(got, want, atol=tol, rtol=0), f"{what}: got {got.tolist()}, expected {want.tolist()}"


def _samples(case):
    s = case["input"]["samples"]
    pred = np.array([x["pred"] for x in s], np.float32)
    gt = np.array([x["gt"] for x in s], np.float32)
    return pred, gt


def _occupancy(case, h=olm.HORIZON):
    """(N, H, 200, 200) bool from the case's inclusive "rects"."""
    samples = case["input"]["samples"]
    occ = np.zeros((len(samples), h, olm.BEV_SIZE, olm.BEV_SIZE), bool)
    for i, s in enumerate(samples):
        for steps, r0, r1, c0, c1 in s["rects"]:
            for t in steps:
                occ[i, t, r0 : r1 + 1, c0 : c1 + 1] = True
    return occ


def check_ol01(case: dict) -> None:
    """OL-01: per-step L2 and the UniAD / ST-P3 / VAD conventions."""
    tol = case["tolerance"]["abs"]
    exp = case["expected"]
    pred, gt = _samples(case)
    res = olm.l2_metrics(pred, gt)
    _close(res["per_step"], exp["per_step_L2"], tol, "OL-01 per-step L2")
    _close(res["uniad"], exp["uniad_convention_L2_1s_2s_3s"], tol, "OL-01 UniAD L2")
    _close(res["stp3"], exp["stp3_convention_L2_1s_2s_3s"], tol, "OL-01 ST-P3 L2")
    _close(olm.vad_l2(pred, gt), exp["vad_plan_L2_1s_2s_3s"], tol, "OL-01 VAD L2")


def check_ol04(case: dict) -> None:
    """OL-04: UniAD raster obj_col / obj_box_col with the GT exclusion, and L2."""
    tol = case["tolerance"]["abs"]
    exp = case["expected"]
    pred, gt = _samples(case)
    occ = _occupancy(case, pred.shape[1])
    rates = olm.uniad_collision_rates(pred, gt, occ)
    for name in ("obj_col", "obj_box_col"):
        _close(rates[name]["per_step"], exp[name]["per_step"], tol, f"OL-04 {name} per step")
        _close(rates[name]["uniad"], exp[name]["uniad_1s_2s_3s"], tol, f"OL-04 {name} UniAD")
        _close(rates[name]["stp3"], exp[name]["stp3_1s_2s_3s"], tol, f"OL-04 {name} ST-P3")
    l2 = olm.l2_metrics(pred, gt)
    _close(l2["per_step"], exp["L2"]["per_step"], tol, "OL-04 L2 per step")
    _close(l2["uniad"], exp["L2"]["uniad_1s_2s_3s"], tol, "OL-04 L2 UniAD")
    _close(l2["stp3"], exp["L2"]["stp3_1s_2s_3s"], tol, "OL-04 L2 ST-P3")
