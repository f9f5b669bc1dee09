"""Grouped bar charts with named groups, drawn in a 2D view.

Rerun's bar chart view numbers its bars (0, 1, ...) and names them in its legend by their entity
paths; these charts name each group under its bars (a pose, a metric), colour each series (an axis,
a model) with a coloured legend above the frame, and label the y ticks with their values and unit.
Layout in view units: the frame spans x 0..W, y 0..H (y grows downwards: larger values up); bars of
group g and series j sit at x = (g + 0.1 + 0.8 (j + 0.5) / n_series) W / n_groups (W: the frame's width).

    y(v) = (top - v) / (top - bottom) H,  top/bottom: the outer "nice" ticks (1-2-5 steps) around
    min(0, values) .. max(0, values); log10=True plots log10(value): ticks 10^k, bars from a floor
    at least half a decade below the smallest value (a value near 1 has a bar, not a line at 1),
    each bar's value written over it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

W, H = 400.0, 240.0
"""Plot frame in view units."""
BARS2D = "bars2d"
"""Role of these entities (their views are built by the caller's blueprint)."""
_GREY = (150, 150, 150)


def nice_ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    """About n ticks on a 1-2-5 step covering lo..hi (both ends included; lo..hi widened by 1 on
    each side when it is empty)."""
    if not hi - lo > 1e-12 * max(1.0, abs(lo), abs(hi)):
        lo, hi = lo - 1.0, hi + 1.0
    span = hi - lo
    raw = span / max(n - 1, 1)
    mag = 10.0 ** np.floor(np.log10(raw))
    step = mag * min((m for m in (1.0, 2.0, 5.0, 10.0) if m * mag >= raw), default=10.0)
    first, last = np.floor(lo / step + 1e-9) * step, np.ceil(hi / step - 1e-9) * step
    return np.round(np.arange(first, last + 0.5 * step, step), 12)


def bar_strip(x: float, y0: float, y1: float, r: float) -> tuple[list[list[float]], float]:
    """A filled bar from y0 to y1 centred on x, r wide on each side, as one line strip and its
    radius (2D boxes are drawn as outlines; a line of radius r is a bar with round caps, so the
    strip is shortened by r at both ends). A bar shorter than 2 r lies flat: a horizontal strip of
    radius half its height. A strip never has zero length (the viewer would not draw it)."""
    h = abs(y1 - y0)
    if h >= 2.0 * r:
        s = 1.0 if y1 > y0 else -1.0
        return [[x, y0 + s * r], [x, y1 - s * r]], r
    rr = max(0.5 * h, 0.3)  # at least a hairline for a zero bar
    yc = 0.5 * (y0 + y1)
    half = max(r - rr, 0.1)
    return [[x - half, yc], [x + half, yc]], rr


def _scale(data: np.ndarray, log10: bool) -> tuple[np.ndarray, float]:
    """(y ticks, where bars start): with log10 whole decades from half a decade or more below the
    smallest value (every bar has a length), else 1-2-5 ticks around 0 and the values."""
    if log10:
        ticks = np.arange(np.floor(float(data.min()) - 0.5), np.ceil(float(data.max())) + 0.5)
        return ticks, float(ticks[0])
    return nice_ticks(min(0.0, float(data.min())), max(0.0, float(data.max()))), 0.0


def _values(rec, entity: str, pos: list, text: list[str]) -> None:
    """Each bar's value written over it."""
    import rerun as rr

    if pos:
        rec.log_static(
            entity, rr.Points2D(pos, labels=text, radii=0.1, colors=[(220, 220, 220)] * len(pos)), BARS2D
        )


def _tick_text(v: float, log10: bool, unit: str) -> str:
    txt = f"{10.0**v:g}" if log10 else f"{v:g}"
    return f"{txt} {unit}".strip()


def log_bar_groups(
    rec,
    entity: str,
    groups: Sequence[str],
    series: Sequence[str],
    colors: Sequence[tuple[int, int, int]],
    values: np.ndarray,
    *,
    unit: str = "",
    log10: bool = False,
    width: float = W,
) -> None:
    """Static 2D bar chart at entity: values (n_groups, n_series), NaN (or <= 0 with log10) = no
    bar; group names below the frame, series names (in their colours) above it, y ticks in unit;
    width: of the frame in view units (its height is H; a wide view wants a wide frame)."""
    import rerun as rr

    raw = np.asarray(values, dtype=np.float64).reshape(len(groups), len(series))
    v = raw
    if log10:
        v = np.where(raw > 0, np.log10(np.where(raw > 0, raw, 1.0)), np.nan)
    ok = np.isfinite(v)
    ticks, base = _scale(v[ok] if ok.any() else np.zeros(1), log10)
    top, bottom = float(ticks[-1]), float(ticks[0])

    def sy(x):
        return (top - np.asarray(x, dtype=np.float64)) / max(top - bottom, 1e-12) * H

    slot = width / len(groups)
    bw = 0.8 * slot / len(series)
    strips, radii, cols, tops, shown = [], [], [], [], []
    for g in range(len(groups)):
        for j in range(len(series)):
            if ok[g, j]:
                x = g * slot + 0.1 * slot + (j + 0.5) * bw
                strip, r = bar_strip(x, float(sy(base)), float(sy(v[g, j])), 0.42 * bw)
                strips.append(strip)
                radii.append(r)
                cols.append(colors[j])
                tops.append([x, float(sy(max(v[g, j], base))) - 22.0])
                shown.append(f"{raw[g, j]:.3g}")
    y_base = float(sy(base))
    box: list[list[float]] = [[0, 0], [width, 0], [width, H], [0, H], [0, 0]]
    rec.log_static(
        f"{entity}/frame",
        rr.LineStrips2D(
            [box, [[0, y_base], [width, y_base]]],
            colors=[_GREY, (90, 90, 90)],
            radii=0.6,
        ),
        BARS2D,
    )
    if strips:
        rec.log_static(
            f"{entity}/bars", rr.LineStrips2D(strips, colors=cols, radii=radii, draw_order=-1.0), BARS2D
        )
    if log10 and bw >= 100.0:  # a log scale is read by its values (where they fit)
        _values(rec, f"{entity}/values", tops, shown)
    two_rows = len(groups) > 4 and max(len(g) for g in groups) * 7 > slot
    pos = [[(g + 0.5) * slot, H + 14 + (12 if two_rows and g % 2 else 0)] for g in range(len(groups))]
    pos += [[-34.0, float(sy(t))] for t in ticks]
    txt = list(groups) + [_tick_text(float(t), log10, unit) for t in ticks]
    rec.log_static(
        f"{entity}/ticks",
        rr.Points2D(pos, labels=txt, radii=0.1, colors=[(200, 200, 200)] * len(txt)),
        BARS2D,
    )
    if len(series) > 1 or series[0]:
        step = width / len(series)
        rec.log_static(
            f"{entity}/legend",
            rr.Points2D(
                [[(j + 0.5) * step, -14.0] for j in range(len(series))],
                labels=list(series),
                colors=list(colors),
                radii=0.1,
            ),
            BARS2D,
        )
