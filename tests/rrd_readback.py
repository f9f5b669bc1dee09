"""Load a written .rrd back into numpy for tests (rerun.chunk.RrdReader + pyarrow; no viewer)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from rerun.chunk import RrdReader

NS = 1e9


@dataclass
class Rrd:
    """Every chunk of the first recording of an .rrd, grouped by entity path (leading '/')."""

    path: Path
    chunks: dict[str, list[pa.RecordBatch]]
    blueprint: dict[str, dict[str, list]]

    @property
    def entities(self) -> set[str]:
        return set(self.chunks)

    def _table(self, entity: str, component: str) -> pa.Table:
        ent = entity if entity.startswith("/") else "/" + entity
        batches = [b for b in self.chunks.get(ent, []) if component in b.schema.names]
        if not batches:
            raise KeyError(f"{ent} has no {component} (has {self.components(ent)})")
        cols = sorted(set.intersection(*[set(b.schema.names) for b in batches]))
        return pa.Table.from_batches([b.select(cols) for b in batches])

    def components(self, entity: str) -> set[str]:
        ent = entity if entity.startswith("/") else "/" + entity
        return {n for b in self.chunks.get(ent, []) for n in b.schema.names}

    def series(self, entity: str, timeline: str = "sensor_time") -> tuple[np.ndarray, np.ndarray]:
        """(t, values (N,k)) of a Scalars entity sorted by the timeline; t in s for durations."""
        tbl = self._table(entity, "Scalars:scalars")
        col = tbl["Scalars:scalars"].combine_chunks()
        lens = pc.list_value_length(col).to_numpy(zero_copy_only=False)
        vals = pc.list_flatten(col).to_numpy(zero_copy_only=False).reshape(len(tbl), int(lens.max()))
        tcol = tbl[timeline].combine_chunks()
        if pa.types.is_duration(tcol.type):
            t = tcol.cast(pa.int64()).to_numpy(zero_copy_only=False) / NS
        else:
            t = tcol.cast(pa.int64()).to_numpy(zero_copy_only=False)
        order = np.argsort(t, kind="stable")
        return t[order], vals[order]

    def texts(self, entity: str, component: str = "TextLog:text") -> list[tuple[float, str]]:
        """(sensor time s, text) rows of a TextLog (or static text: time NaN)."""
        tbl = self._table(entity, component)
        txt = [v[0] if isinstance(v, list) else v for v in tbl[component].to_pylist()]
        if "sensor_time" in tbl.column_names:
            t = tbl["sensor_time"].combine_chunks().cast(pa.int64()).to_numpy(zero_copy_only=False) / NS
        else:
            t = np.full(len(txt), np.nan)
        return sorted(zip(t.tolist(), txt, strict=True), key=lambda r: r[0])

    def static(self, entity: str, component: str) -> list:
        """Values of a static component (last row), e.g. ('/world/tracks/raw/final', 'Points3D:positions')."""
        tbl = self._table(entity, component)
        return tbl[component].to_pylist()[-1]

    def labels(self, prefix: str) -> list[str]:
        """Every Points2D label of the entities under prefix (labels come in groups of <= 30: the
        viewer hides them all beyond that), in entity order."""
        ent = prefix if prefix.startswith("/") else "/" + prefix
        under = sorted(e for e in self.chunks if e == ent or e.startswith(ent + "/"))
        return [
            lab
            for e in under
            if "Points2D:labels" in self.components(e)
            for lab in self.static(e, "Points2D:labels")
        ]

    def bar_values(self, entity: str) -> np.ndarray:
        """Values of a static BarChart (1-D float64)."""
        return np.asarray(self.static(entity, "BarChart:values")[0]["buffer"], dtype=np.float64)

    def ladder_bars(self, metric: str) -> list[tuple[float, str, float]]:
        """(abscissa, entity name, value) of the one-bar charts under /ladder/<metric>, by abscissa."""
        out = []
        for ent in self.entities:
            if ent.startswith(f"/ladder/{metric}/"):
                x = self.static(ent, "BarChart:abscissa")[0]["buffer"]
                out.append((float(x[0]), ent.rsplit("/", 1)[1], float(self.bar_values(ent)[0])))
        return sorted(out)

    def views(self) -> list[dict]:
        """Blueprint views: class ('TimeSeries', 'Spatial3D', 'BarChart', ...), origin, name, contents,
        time_range and axis_range ((start, end) s on sensor_time, or None)."""
        out = []
        for ent, comps in self.blueprint.items():
            if "ViewBlueprint:class_identifier" in comps:
                contents = self.blueprint.get(ent + "/ViewContents", {}).get("ViewContents:query", [])
                ranges = self.blueprint.get(ent + "/VisibleTimeRanges", {}).get(
                    "VisibleTimeRanges:ranges", []
                )
                axis = self.blueprint.get(ent + "/TimeAxis", {}).get("TimeAxis:view_range", [None])[0]
                out.append(
                    {
                        "class": comps["ViewBlueprint:class_identifier"][0],
                        "origin": comps.get("ViewBlueprint:space_origin", [""])[0],
                        "name": (comps.get("ViewBlueprint:display_name") or [""])[0],
                        "contents": contents,
                        "time_range": _seconds(ranges[0]["range"]) if ranges else None,
                        "axis_range": _seconds(axis) if axis else None,
                    }
                )
        return out

    def time_panel(self) -> dict[str, list]:
        return self.blueprint.get("/time_panel", {})


def _seconds(r: dict) -> tuple[float | None, float | None]:
    """(start, end) in s of a blueprint time range (None: unbounded or cursor-relative)."""
    return tuple(None if r.get(k) is None else r[k] / NS for k in ("start", "end"))


def _flat(v):
    while isinstance(v, list) and len(v) == 1:
        v = v[0]
    return v


def load_rrd(path: str | Path) -> Rrd:
    """Read the first recording and the first blueprint of an .rrd."""
    r = RrdReader(str(path))
    chunks: dict[str, list[pa.RecordBatch]] = {}
    for c in r.stream().to_chunks():
        chunks.setdefault(str(c.entity_path), []).append(c.to_record_batch())
    bp: dict[str, dict[str, list]] = {}
    bps = r.blueprints()
    if bps:
        for c in r.stream(store=bps[-1]).to_chunks():
            b = c.to_record_batch()
            d = bp.setdefault(str(c.entity_path), {})
            for name in b.schema.names:
                if ":" in name and not name.startswith("rerun."):
                    vals = b.column(name).to_pylist()
                    if vals and vals[-1] is not None:
                        v = vals[-1]
                        d[name] = [_flat(x) for x in v] if isinstance(v, list) else [v]
    return Rrd(Path(path), chunks, bp)
