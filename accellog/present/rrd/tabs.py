"""Pick a tab of a recording's saved blueprint: ``accellog view F.rrd --tab NAME``.

The .rrd's (last) blueprint is read back with rerun.chunk.RrdReader, the container or view whose
display name is NAME is found, and a blueprint file (.rbl) is written with the same chunks plus, at a
later blueprint time, ``active_tab`` set on every Tabs container between the root and NAME. The
recording itself is never modified: ``tab_view_files`` writes a copy of its data without any
blueprint (the saved layout is activated when the file is loaded, so it could win over the .rbl in
a viewer that reads both files in parallel), and the viewer opens that copy with the .rbl.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from accellog.core.errors import InputError

TABS_KIND = 1
"""ContainerKind of a Tabs container in Rerun's blueprint store."""


@dataclass
class _Node:
    name: str | None = None
    kind: int | None = None
    children: list[str] = field(default_factory=list)
    max_time: int = 0


def _last(batch, column: str):
    if column not in batch.schema.names:
        return None
    vals = [v for v in batch.column(column).to_pylist() if v is not None]
    return vals[-1] if vals else None


def _blueprint_nodes(chunks) -> tuple[dict[str, _Node], int]:
    """Entity path (no leading '/') -> display name, container kind, children; and the last blueprint time."""
    nodes: dict[str, _Node] = {}
    t_max = 0
    for c in chunks:
        b = c.to_record_batch()
        ent = str(c.entity_path).lstrip("/")
        n = nodes.setdefault(ent, _Node())
        if "blueprint" in b.schema.names:
            ts = [t for t in b.column("blueprint").to_pylist() if t is not None]
            t_max = max([t_max, *ts])
        for col in ("ContainerBlueprint:display_name", "ViewBlueprint:display_name"):
            v = _last(b, col)
            if v is not None:
                n.name = v[0] if isinstance(v, list) else v
        kind = _last(b, "ContainerBlueprint:container_kind")
        if kind is not None:
            n.kind = int(kind[0] if isinstance(kind, list) else kind)
        kids = _last(b, "ContainerBlueprint:contents")
        if kids is not None:
            n.children = [str(k).lstrip("/") for k in kids]
    return nodes, t_max


def tab_names(nodes: dict[str, _Node]) -> list[str]:
    """Display names of the children of every Tabs container (what --tab accepts)."""
    return [
        name
        for n in nodes.values()
        if n.kind == TABS_KIND
        for k in n.children
        if k in nodes and (name := nodes[k].name)
    ]


def tab_blueprint(rrd_path: str | Path, tab: str, out_rbl: str | Path) -> Path:
    """Write out_rbl: the .rrd's blueprint with the tab named `tab` (case-insensitive) active.
    InputError (naming the tabs there are) when the recording has no blueprint or no such tab."""
    import rerun as rr
    import rerun.blueprint as rrb
    from rerun import bindings
    from rerun.chunk import RrdReader

    reader = RrdReader(str(rrd_path))
    stores = reader.blueprints()
    if not stores:
        raise InputError("the recording has no saved blueprint (no tabs to pick)", where=str(rrd_path))
    chunks = list(reader.stream(store=stores[-1]).to_chunks())
    nodes, t_max = _blueprint_nodes(chunks)
    want = [k for k, n in nodes.items() if n.name and n.name.casefold() == tab.casefold()]
    if not want:
        raise InputError(
            f"no tab {tab!r}; tabs: {', '.join(repr(t) for t in tab_names(nodes))}", where=str(rrd_path)
        )
    parent = {c: k for k, n in nodes.items() for c in n.children}
    node, switch = want[0], []
    while node in parent:
        up = parent[node]
        if nodes[up].kind == TABS_KIND:
            switch.append((up, node))
        node = up
    if not switch:
        raise InputError(f"{tab!r} is not inside a tab container", where=str(rrd_path))
    stream = rr.RecordingStream._from_native(
        bindings.new_blueprint(
            application_id=stores[-1].application_id,
            make_default=False,
            make_thread_default=False,
            default_enabled=True,
        )
    )
    stream.send_chunks(chunks)
    stream.set_time("blueprint", sequence=t_max + 1)
    for container, child in switch:
        stream.log(container, rrb.archetypes.ContainerBlueprint.from_fields(active_tab=child))
    out = Path(out_rbl)
    bindings.save_blueprint(str(out), stream.to_native())
    return out


def recording_only(rrd_path: str | Path, out_rrd: str | Path) -> Path:
    """Write out_rrd: the first recording of rrd_path (its data chunks, same application and
    recording id) without any blueprint."""
    import rerun as rr
    from rerun.chunk import RrdReader

    reader = RrdReader(str(rrd_path))
    entries = reader.recordings()
    if not entries:
        raise InputError("the file holds no recording", where=str(rrd_path))
    e = entries[0]
    rec = rr.RecordingStream(e.application_id, recording_id=e.recording_id, send_properties=False)
    out = Path(out_rrd)
    rec.save(str(out))
    rec.send_chunks(list(reader.stream(store=e).to_chunks()))
    rec.flush()
    rec.disconnect()
    return out


def tab_view_files(rrd_path: str | Path, tab: str, out_dir: str | Path) -> tuple[Path, Path]:
    """(the recording without its blueprints, the blueprint with `tab` active) in out_dir: what a
    viewer opens to show that tab."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    rbl = tab_blueprint(rrd_path, tab, d / "tab.rbl")
    return recording_only(rrd_path, d / "recording.rrd"), rbl
