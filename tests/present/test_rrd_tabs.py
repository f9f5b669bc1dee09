"""`accellog view --tab NAME`: the recording's blueprint, read back, with the named tab active in a
.rbl written beside it (the recording is not modified); unknown names are refused in one line."""

from __future__ import annotations

import numpy as np
import pytest
from rerun.chunk import RrdReader

from accellog.core.errors import InputError
from accellog.present.rrd.recording import RunRecording
from accellog.present.rrd.tabs import TABS_KIND, _blueprint_nodes, tab_blueprint


def _active_tabs(path) -> dict[str, list]:
    """Container -> active_tab values in blueprint-time order."""
    r = RrdReader(str(path))
    out: dict[str, list] = {}
    for c in r.stream(store=r.blueprints()[-1]).to_chunks():
        b = c.to_record_batch()
        if "ContainerBlueprint:active_tab" in b.schema.names:
            times = b.column("blueprint").to_pylist()
            vals = b.column("ContainerBlueprint:active_tab").to_pylist()
            for _t, v in sorted(zip(times, vals, strict=True)):
                if v is not None:
                    out.setdefault(str(c.entity_path).lstrip("/"), []).append(
                        v[0] if isinstance(v, list) else v
                    )
    return out


def test_tab_blueprint_activates_the_named_tab(tmp_path):
    rrd = tmp_path / "docs.rrd"
    with RunRecording(f"save:{rrd}") as rec:
        rec.log_samples("raw", np.arange(10.0), None, np.zeros((10, 3)), "g")
        rec.log_document("first", "# one")
        rec.log_document("second", "# two")
    before = rrd.read_bytes()
    rbl = tab_blueprint(rrd, "SECOND", tmp_path / "tab.rbl")  # case-insensitive
    r = RrdReader(str(rbl))
    nodes, _ = _blueprint_nodes(list(r.stream(store=r.blueprints()[-1]).to_chunks()))
    (tabs,) = [
        k
        for k, n in nodes.items()
        if n.kind == TABS_KIND and any(nodes[c].name == "second" for c in n.children)
    ]
    second = next(c for c in nodes[tabs].children if nodes[c].name == "second")
    assert _active_tabs(rbl)[tabs][-1] == second  # the last write (latest blueprint time) wins
    assert rrd.read_bytes() == before
    with pytest.raises(InputError, match=r"no tab 'third'; tabs: .*'first', 'second'"):
        tab_blueprint(rrd, "third", tmp_path / "x.rbl")
    assert not (tmp_path / "x.rbl").exists()


def test_tab_view_files_copy_the_data_without_its_blueprint(tmp_path):
    """The viewer gets the recording's data without the saved (activated) layout, so the .rbl decides."""
    import sys
    from pathlib import Path

    from accellog.present.rrd.tabs import tab_view_files

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from rrd_readback import load_rrd

    rrd = tmp_path / "docs.rrd"
    v = np.random.default_rng(1).normal(size=(50, 3))
    with RunRecording(f"save:{rrd}") as rec:
        rec.log_samples("raw", np.arange(50.0), None, v, "g")
        rec.log_document("first", "# one")
        rec.log_document("second", "# two")
    before = rrd.read_bytes()
    data, rbl = tab_view_files(rrd, "second", tmp_path / "view")
    assert RrdReader(str(data)).blueprints() == [] and RrdReader(str(rbl)).blueprints()
    assert RrdReader(str(data)).recordings() == RrdReader(str(rrd)).recordings()
    np.testing.assert_array_equal(load_rrd(data).series("accel/raw")[1], v)
    assert rrd.read_bytes() == before
