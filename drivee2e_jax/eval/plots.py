"""The PNG figures of a run report (host side, matplotlib Agg, no pyplot state).

``write_plots(folder, ...)`` draws, each written atomically (temp file in the
same folder + ``os.replace``):

* ``sr_by_behavior.png`` / ``ds_by_behavior.png``: grouped bars, one colour per
  policy, x = behaviour group (with its size); error bars = std over
  repetitions when there are several.
* ``infractions_per_km.png``: horizontal grouped bars, one row per infraction
  or event type that occurred (for some policy), one bar per policy: events per km driven
  (LB 2.0's rate, km = route length x RC); error bars = std over repetitions.
  Left out when no policy has any event.
* ``comfort.png``: one box plot panel per comfort column (physical jerk and
  Bench2Drive smoothness), one box per policy, pooled over repetitions.
  Left out when ``scenarios.csv`` has none of them.

Only what depends on the policy is drawn; scenario properties (route length,
speed limit) would look the same for every policy.

Figures are made with matplotlib's object API (``Figure`` + the Agg canvas), never pyplot.
"""

from __future__ import annotations

import math
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from drivee2e_jax.files import atomic_write

#: Distinct, colour-blind-friendly enough for up to 10 policies (tab10).
_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
           "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")
_LABELS = {"driving_score": "Driving score DS", "route_completion": "Route completion RC %",
           "success_rate": "Success rate SR %", "jerk_lon_mean_mps3": "Jerk: mean |Δa|/Δt, m/s³",
           "smoothness_pct": "B2D smoothness %\n(20-step chunks within bounds)"}


def write_plots(folder: Path, policies: list[str], groups: list[str], sizes: list[int], sr: dict, ds: dict,
                infractions: dict[str, dict[str, tuple[float, float] | None]],
                comfort: dict[str, dict[str, list[float]]], repetitions: int) -> dict[str, str]:
    """Draw every figure into ``folder``; returns {name: path relative to the run folder}.

    Args:
      policies: names, in legend order.
      groups, sizes: behaviour groups and their scenario counts.
      sr, ds: {policy: [(mean, std) or None per group]}, % and DS points.
      infractions: {event type: {policy: (mean, std) events per km, or None}}.
      comfort: {column: {policy: per-episode values}}.
      repetitions: how many repetitions the means are over (titles only).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    reps = f"\n(mean ± std over {repetitions} repetitions)" if repetitions > 1 else ""
    out = {}
    if groups:
        for name, values, label in (("sr_by_behavior", sr, "Success rate SR %"), ("ds_by_behavior", ds, "Driving score DS")):
            _save(grouped_bars(policies, groups, sizes, values, label, f"{label} by behaviour group{reps}"),
                  folder / f"{name}.png")
            out[name] = f"{folder.name}/{name}.png"
    occurred = {k: per for k, per in infractions.items() if any(v and v[0] > 0 for v in per.values())}
    if occurred:
        _save(infraction_bars(policies, occurred, f"Infractions and events per km driven{reps}\n"
                                                  "(types without any event left out)"),
              folder / "infractions_per_km.png")
        out["infractions_per_km"] = f"{folder.name}/infractions_per_km.png"
    if comfort:
        _save(distributions_grid(policies, comfort, "Comfort per episode (box: quartiles, whiskers 1.5 IQR, ◇ mean)"),
              folder / "comfort.png")
        out["comfort"] = f"{folder.name}/comfort.png"
    return out


def infraction_bars(policies, rates: dict[str, dict[str, tuple[float, float] | None]], title: str):
    """Horizontal bars: a row per event type (``rates`` order, top down), a bar per policy.

    ``rates[type][policy]`` is (mean, std) events per km, or None (no km driven: no bar)."""
    kinds = list(rates)
    fig = Figure(figsize=(8.5, 1.2 + 0.28 * len(kinds) * max(len(policies), 2)), layout="constrained")
    ax = fig.add_subplot()
    height = 0.8 / max(len(policies), 1)
    for i, p in enumerate(policies):
        ys = [len(kinds) - 1 - k + ((len(policies) - 1) / 2 - i) * height for k in range(len(kinds))]
        vals = [rates[k].get(p) for k in kinds]
        ms = [v[0] if v else math.nan for v in vals]
        errs = [v[1] if v else 0.0 for v in vals]
        bars = ax.barh(ys, ms, height * 0.92, color=_color(i), label=p,
                       xerr=errs if any(errs) else None, capsize=2, error_kw={"elinewidth": 0.8})
        ax.bar_label(bars, fmt="{:.2f}", fontsize=6.5, padding=1.5)
    ax.set_yticks(range(len(kinds)), kinds[::-1], fontsize=8)
    ax.set_xlabel("events per km driven")
    ax.margins(x=0.15)
    ax.set_title(title)
    ax.grid(axis="x", alpha=0.3)
    ax.set_axisbelow(True)
    fig.legend(loc="outside right upper", frameon=False, title="policy")
    return fig


def grouped_bars(policies, groups, sizes, values: dict[str, list], ylabel: str, title: str):
    """Bars per group, one per policy; ``values[policy][i]`` is (mean, std) or None. Scale 0-100."""
    width_in = min(16.0, max(8.0, 0.4 * len(groups) * max(len(policies), 2) + 2.5))
    fig = Figure(figsize=(width_in, 4.5), layout="constrained")
    ax = fig.add_subplot()
    width = 0.8 / max(len(policies), 1)
    for i, p in enumerate(policies):
        xs = [g + (i - (len(policies) - 1) / 2) * width for g in range(len(groups))]
        ms = [v[0] if v else math.nan for v in values[p]]
        errs = [v[1] if v else 0.0 for v in values[p]]
        bars = ax.bar(xs, ms, width * 0.92, color=_color(i), label=p,
                      yerr=errs if any(errs) else None, capsize=2, error_kw={"elinewidth": 0.8})
        # values on the bars, so a 0 is told apart from a missing group
        ax.bar_label(bars, fmt="{:.0f}", fontsize=6.5, padding=1.5, rotation=90 if len(policies) > 4 else 0)
    ax.set_xticks(range(len(groups)), [f"{g}\nn={n}" for g, n in zip(groups, sizes)])
    ax.set_ylim(0, 112)
    ax.set_yticks(range(0, 101, 20))
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
    ax.set_axisbelow(True)
    fig.legend(loc="outside right upper", frameon=False, title="policy")
    return fig


def distributions_grid(policies, distributions: dict[str, dict[str, list[float]]], title: str):
    """One box-plot panel per column; a box per policy (white diamond = mean)."""
    cols = list(distributions)
    nrows = math.ceil(len(cols) / 4)
    ncols = math.ceil(len(cols) / nrows)  # balanced rows: 5 panels -> 3 + 2, not 4 + 1
    fig = Figure(figsize=(3.2 * ncols + 1.8, 3.0 * nrows + 0.4), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    # policy names under the boxes only while they fit; the colour legend always names them
    named = len(policies) <= 4 and max(map(len, policies), default=0) <= 12
    for ax, col in zip(axes, cols):
        data = [distributions[col].get(p, []) for p in policies]
        box = ax.boxplot(data, patch_artist=True, showmeans=True, widths=0.6,
                         meanprops={"marker": "D", "markerfacecolor": "white", "markeredgecolor": "black",
                                    "markersize": 4},
                         medianprops={"color": "black"}, flierprops={"markersize": 2.5, "alpha": 0.5})
        for i, patch in enumerate(box["boxes"]):
            patch.set_facecolor(_color(i))
            patch.set_alpha(0.8)
        ax.set_title(_LABELS.get(col, col), fontsize=10)
        ax.set_xticks(range(1, len(policies) + 1), policies if named else [""] * len(policies), fontsize=8)
        ax.grid(axis="y", alpha=0.3)
        ax.set_axisbelow(True)
    for ax in axes[len(cols):]:
        ax.set_visible(False)
    handles = [_patch(_color(i)) for i in range(len(policies))]
    fig.legend(handles, policies, loc="outside right upper", frameon=False, title="policy")
    fig.suptitle(title, fontsize=10)
    return fig


def _patch(color):
    return Patch(facecolor=color, alpha=0.8, edgecolor="black")


def _color(i: int) -> str:
    return _COLORS[i % len(_COLORS)]


def _save(fig, path: Path, dpi: int = 130) -> None:
    """Render ``fig`` with Agg and write the PNG atomically."""
    FigureCanvasAgg(fig)
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=dpi), binary=True)
