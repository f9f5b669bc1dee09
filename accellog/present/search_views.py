"""The workbench's search in a Rerun recording: every model tried, its held-out residual on the
common yardstick, and the curve the path of the search draws through them.

One 2D bar chart at ``/charts/search`` (role ``search2d``): a bar per trail row (accellog.flows.
workbench_trail.TrailStep, duck-typed) in the order the search met them, its height log10 of the
held-out chi2/dof (the out-of-sample chi2/eq without a held-out session) from a floor half a decade
below the smallest, its value written over it (chi2/dof and RMS in mg), its step, change and what
became of it below; a line joins the models the search walked (start, each addition, each removal),
the curve that should fall. A model of the ladder has its ladder step's colour (the same
calibration, the same colour in every panel); a model not kept is grey, a side branch (tied,
rejected) darker. The table is ``/docs/search``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from accellog.present.discovery_text import TRAIL_STATUS
from accellog.present.rrd.bars2d import bar_strip
from accellog.present.rrd.entities import CHARTS
from accellog.present.rrd.logs import step_color

SEARCH = f"{CHARTS}/search"
ROLE = "search2d"
W, H = 1200.0, 260.0
"""Chart frame in view units."""
GREY, DARK = (140, 140, 140), (85, 85, 85)
LABELS_PER_ENTITY = 24
"""The Rerun viewer hides every label of an entity that has more than 30: labels go in groups."""


def _terms(model: str) -> frozenset[str]:
    return frozenset(model.split("+"))


def trail_colors(trail, ladder: Sequence) -> list[tuple[int, int, int]]:
    """Per trail row: the colour of the ladder step with the same model (its set of terms), else grey
    (on the path) or dark grey (a tied or rejected side branch)."""
    steps = {_terms(r.model): step_color(i) for i, r in enumerate(ladder)}
    return [steps.get(_terms(t.model), GREY if t.on_path else DARK) for t in trail]


def _values(trail) -> tuple[list[float | None], str]:
    if any(t.heldout is not None for t in trail):
        return [t.heldout_chi2_dof for t in trail], "held-out χ²/dof on one yardstick"
    return [t.score for t in trail], "out-of-sample χ²/eq (no held-out session)"


def log_search(rec, trail, ladder: Sequence = ()) -> None:
    """The search chart and table (module doc); nothing for an empty trail."""
    import rerun as rr

    if not trail:
        return
    vals, what = _values(trail)
    logv = np.array([np.log10(v) if v is not None and v > 0 else np.nan for v in vals])
    ok = np.isfinite(logv)
    lo = float(np.nanmin(logv)) if ok.any() else 0.0
    hi = float(np.nanmax(logv)) if ok.any() else 1.0
    ticks = np.arange(np.floor(lo - 0.5), np.ceil(hi) + 0.5)
    bottom = float(ticks[0])
    top = max(hi + 0.3 * (hi - bottom), bottom + 1.0)  # room over the highest bar for its values
    ticks = ticks[ticks <= top]

    def sy(v):
        return (top - np.asarray(v, float)) / (top - bottom) * H

    slot = W / len(trail)
    cols = trail_colors(trail, ladder)
    strips, radii, colors, tops, texts, path = [], [], [], [], [], []
    for k, t in enumerate(trail):
        x = (k + 0.5) * slot
        if not ok[k]:
            continue
        strip, r = bar_strip(x, float(sy(bottom)), float(sy(logv[k])), min(0.2 * slot, 24.0))
        strips.append(strip)
        radii.append(r)
        colors.append(cols[k])
        y_top = float(sy(logv[k]))  # a label is one line: the value, and the RMS above it
        tops += [[x, y_top - 20.0]] + ([] if t.heldout_rms_mg is None else [[x, y_top - 44.0]])
        texts += [f"{vals[k]:.3g}"] + ([] if t.heldout_rms_mg is None else [f"{t.heldout_rms_mg:.3g} mg"])
        if t.on_path:
            path.append([x, float(sy(logv[k]))])
    frame: list[list[float]] = [[0, 0], [W, 0], [W, H], [0, H], [0, 0]]
    rec.log_static(f"{SEARCH}/frame", rr.LineStrips2D([frame], colors=[(150, 150, 150)], radii=0.6), ROLE)
    if strips:
        rec.log_static(
            f"{SEARCH}/bars", rr.LineStrips2D(strips, colors=colors, radii=radii, draw_order=-1.0), ROLE
        )
    if len(path) > 1:
        rec.log_static(f"{SEARCH}/path", rr.LineStrips2D([path], colors=[(235, 235, 235)], radii=1.6), ROLE)
    pos, labels = [], []  # below each bar: its step and change, and what became of it (one line each)
    for k, t in enumerate(trail):
        y = H + 18 + (48 if len(trail) > 6 and k % 2 else 0)
        pos += [[(k + 0.5) * slot, y], [(k + 0.5) * slot, y + 22]]
        labels += [
            f"{t.step} {t.change}",
            TRAIL_STATUS.get(t.status, t.status) + (" = final" if t.final else ""),
        ]
    groups = {
        "steps": (pos, labels),
        "ticks": ([[-40.0, float(sy(v))] for v in ticks], [f"{10.0**v:g}" for v in ticks]),
        "values": (tops, texts),
    }
    for name, (p, t) in groups.items():  # the viewer draws no label of an entity with > 30 of them
        for i in range(0, len(t), LABELS_PER_ENTITY):
            sl = slice(i, i + LABELS_PER_ENTITY)
            rec.log_static(
                f"{SEARCH}/labels/{name}/{i // LABELS_PER_ENTITY}",
                rr.Points2D(p[sl], labels=t[sl], radii=0.1, colors=[(210, 210, 210)] * len(t[sl])),
                ROLE,
            )
    caption = f"{what} of every model the search tried (log scale); line: the models it walked through"
    rec.log_static(
        f"{SEARCH}/legend",
        rr.Points2D([[W / 2, -22.0]], labels=[caption], colors=[(210, 210, 210)], radii=0.1),
        ROLE,
    )
    rec.log_document("search", search_markdown(trail))


def search_markdown(trail) -> str:
    """The trail as a markdown table (step, change, what became of it, held-out chi2/dof and RMS, why)."""
    vals, what = _values(trail)
    md = [
        "### The search, step by step\n",
        f"| step | change | what became of it | {what} | held-out RMS (mg) | why |",
        "|---|---|---|---|---|---|",
    ]
    for t, v in zip(trail, vals, strict=True):
        status = TRAIL_STATUS.get(t.status, t.status) + (" = **final**" if t.final else "")
        rms = "-" if t.heldout_rms_mg is None else f"{t.heldout_rms_mg:.3g}"
        val = "-" if v is None else f"{v:.3g}"
        md.append(f"| {t.step} | {t.change} | {status} | {val} | {rms} | {t.why.replace('|', '/')} |")
    return "\n".join(md) + "\n"
