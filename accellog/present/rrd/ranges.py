"""Every time-series view shows its own data's time range (issue 10: no view cut to the last ~30 s).

``with_time_ranges(bp, extents)`` walks a blueprint and gives each ``TimeSeriesView`` that has no
range yet the span [t0, t1] (s on ``sensor_time``) of the entities it shows, as both

- ``VisibleTimeRanges``: the data the view queries (absolute bounds, not relative to the cursor), and
- ``TimeAxis(link=Independent, view_range=...)``: the x axis it opens with (a globally linked axis
  would share one range across tabs, e.g. a calibration and a held-out session).

Which entities a view shows follows its contents expressions (``$origin/**``, ``/path/**``,
``/path``, ``+ ``/``- `` prefixes); the range is that of the shown entities under the view's origin
(overlays such as hold windows drawn in every sample view do not widen it), or of all shown
entities for a view rooted at '/'. ``extents`` maps entity path (no leading '/') -> (t0, t1) and is
collected by ``RunRecording`` as it logs.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from accellog.present.rrd.entities import MAIN_TIMELINE


def _matches(expr: str, entity: str) -> bool:
    path = "/" + entity.strip("/")
    if expr.endswith("/**"):
        base = expr[:-3].rstrip("/") or ""
        return base == "" or path == base or path.startswith(base + "/")
    return path == (expr.rstrip("/") or "/")


def shown_entities(origin: str, contents: Iterable[str] | str, entities: Iterable[str]) -> list[str]:
    """Entities (of `entities`) a view with this origin and contents query shows."""
    exprs = [contents] if isinstance(contents, str) else list(contents or ["$origin/**"])
    org = "/" + str(origin).strip("/")
    inc: list[str] = []
    exc: list[str] = []
    for e in exprs:
        e = str(e).strip()
        target = exc if e.startswith("- ") else inc
        e = e[2:].strip() if e[:2] in ("+ ", "- ") else e
        e = e.replace("$origin", "" if org == "/" else org)
        target.append(e if e.startswith("/") else "/" + e)
    return [
        ent
        for ent in entities
        if any(_matches(x, ent) for x in inc) and not any(_matches(x, ent) for x in exc)
    ]


def time_range_properties(t0_s: float, t1_s: float):
    """(VisibleTimeRange, TimeAxis) for a view covering t0_s..t1_s (s) on sensor_time."""
    import rerun.blueprint as rrb

    b = rrb.TimeRangeBoundary
    lo, hi = float(t0_s), float(t1_s)
    if not hi > lo:
        hi = lo + 1e-3
    visible = rrb.VisibleTimeRange(MAIN_TIMELINE, start=b.absolute(seconds=lo), end=b.absolute(seconds=hi))
    axis = rrb.archetypes.TimeAxis(
        link=rrb.components.LinkAxis.Independent,
        view_range=rrb.components.TimeRange(start=b.absolute(seconds=lo), end=b.absolute(seconds=hi)),
    )
    return visible, axis


def _origin_tree(origin) -> str:
    org = "/" + str(origin).strip("/")
    return "/**" if org == "/" else org + "/**"


def _views(node) -> Iterable:
    if hasattr(node, "class_identifier"):
        yield node
        return
    for child in getattr(node, "contents", None) or []:
        yield from _views(child)


def with_time_ranges(bp, extents: Mapping[str, tuple[float, float]]):
    """bp with every time-series view given its data's range (module doc); views with a bounded
    range of their own, or showing nothing logged on sensor_time, are left alone. Returns bp
    (changed in place)."""
    import rerun.blueprint as rrb

    root = getattr(bp, "root_container", bp)
    for view in _views(root):
        if str(view.class_identifier) != "TimeSeries":
            continue
        whole = _unbounded(view.properties.get("VisibleTimeRanges"))
        if not whole and "VisibleTimeRanges" in view.properties:
            continue
        ents = shown_entities(str(view.origin), view.contents, extents)
        own = [e for e in ents if _matches(_origin_tree(view.origin), e)]
        ents = own or ents  # overlays (hold windows, detected intervals) do not widen a view
        if not ents:
            continue
        visible, axis = time_range_properties(
            min(extents[e][0] for e in ents), max(extents[e][1] for e in ents)
        )
        view.properties["VisibleTimeRanges"] = rrb.archetypes.VisibleTimeRanges(visible)
        if whole or "TimeAxis" not in view.properties:
            view.properties["TimeAxis"] = axis
    return bp


def _unbounded(ranges) -> bool:
    """True for no range at all or for ranges infinite at both ends (a 'whole timeline' view, which
    gets the bounds of its own data instead)."""
    if ranges is None:
        return True
    rows = ranges.ranges.as_arrow_array().to_pylist()
    return all(r["range"]["start"] is None and r["range"]["end"] is None for r in rows)
