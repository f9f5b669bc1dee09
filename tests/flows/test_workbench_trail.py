"""The search trail (accellog.flows.workbench_trail): every model tried, in order — kept, dropped by
a backward step or as a proxy, tied — each with its held-out residual on the common yardstick; in
the text (a table with log-scale bars) and in the .rrd (a bar per model, values written, the
path's falling curve), the bars of values near 1 visible."""

from __future__ import annotations

import io
import sys
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest
from rich.console import Console

from accellog.flows.workbench import Discovery
from accellog.flows.workbench_trail import finish_trail, note_added, note_rejected, note_removed, note_start
from accellog.present.discovery_text import log_bars, search_table
from accellog.present.rrd.recording import RunRecording
from accellog.present.search_views import log_search

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rrd_readback import load_rrd


def _choice(chosen, scores, base, undecided=()):
    return NS(
        chosen=chosen,
        scores={k: NS(chi2_per_eq=v) for k, v in scores.items()},
        base_score=NS(chi2_per_eq=base),
        reason=f"{chosen}: held-out chi2/eq {base} -> {scores.get(chosen)}",
        undecided=list(undecided),
        evidence="heldout",
    )


HELD = {  # held-out chi2/dof of each model on the one yardstick
    frozenset(["model3"]): 300.0,
    frozenset(["model3", "warmup"]): 60.0,
    frozenset(["model3", "temp_bias"]): 65.0,
    frozenset(["model3", "warmup", "nonlin2"]): 3.0,
    frozenset(["model3", "nonlin2"]): 1.2,
    frozenset(["model3", "nonlin2", "temp_bias2"]): 1.25,
    frozenset(["model3", "nonlin2", "time_drift"]): 1.3,
}


def _stats(name: str) -> dict:
    c = HELD[frozenset(name.split("+"))]
    return {"heldout_chi2_dof": c, "heldout_rms_g": 1e-4 * np.sqrt(c), "heldout_noise_g": 1e-4}


def _trail() -> Discovery:
    """start -> +warmup (tied with temp_bias) -> +nonlin2 -> a backward step removes warmup ->
    nothing more transfers (temp_bias2, time_drift rejected); then a proxy removed at the end."""
    out = Discovery(start="model3")
    c1 = _choice("warmup", {"warmup": 50.0, "temp_bias": 51.0}, 250.0, undecided=["temp_bias"])
    note_start(out, c1)
    out.choices.append(c1)
    out.added.append("warmup")
    note_added(out, c1)
    c2 = _choice("nonlin2", {"nonlin2": 2.5}, 50.0)
    out.choices.append(c2)
    out.added.append("nonlin2")
    note_added(out, c2)
    out.added.remove("warmup")
    note_removed(out, "warmup", "backward", "without it the out-of-sample chi2/eq is no worse")
    c3 = _choice(None, {"temp_bias2": 1.3, "time_drift": 1.4}, 1.2)
    out.choices.append(c3)
    note_rejected(out, c3)
    out.added.append("temp_bias2")  # (as if it had been added and pruning removed it)
    note_removed(out, "temp_bias2", "proxy", "a proxy: without it the held-out chi2/dof is 1.2", ["nonlin2"])
    out.added = ["nonlin2"]
    finish_trail(out, _stats)
    return out


def test_trail_rows_statuses_and_the_final_model() -> None:
    out = _trail()
    rows = [(t.step, t.change, t.status) for t in out.trail]
    assert rows == [
        (0, "model3", "start"),
        (1, "+warmup", "dropped"),
        (1, "+temp_bias", "tied"),
        (2, "+nonlin2", "kept"),
        (2, "-warmup", "backward"),
        (3, "+temp_bias2", "rejected"),
        (3, "+time_drift", "rejected"),
        (3, "-temp_bias2", "proxy"),
    ]
    models = [t.model for t in out.trail]
    assert models[2] == "model3+temp_bias" and models[4] == "model3+nonlin2" and models[7] == "model3+nonlin2"
    assert [t.final for t in out.trail] == [False] * 7 + [True]  # the last path row of the final model
    assert [t.heldout_chi2_dof for t in out.trail][:4] == [300.0, 60.0, 65.0, 3.0]
    assert "later removed" in out.trail[1].why and "does not predict" in out.trail[5].why
    assert not out.trail[2].on_path and not out.trail[5].on_path and out.trail[4].on_path
    assert out.trail[4].to_dict()["heldout_rms_mg"] == pytest.approx(0.1 * np.sqrt(1.2))


def test_trail_text_table_with_log_bars() -> None:
    out = _trail()
    buf = io.StringIO()
    Console(file=buf, width=200).print(search_table(out.trail))
    text = buf.getvalue()
    for s in (
        "tied, not taken",
        "added, dropped later",
        "removed (backward step)",
        "removed (proxy) = final",
    ):
        assert s in text, s
    bars = log_bars([300.0, 1.2, None, 0.9])
    assert len(bars[0]) > len(bars[1]) > len(bars[3]) > 0 and bars[2] == ""  # 0.9 still has a bar


def test_trail_in_the_rrd_a_bar_per_model_values_and_the_falling_path(tmp_path: Path) -> None:
    out = _trail()
    rrd = tmp_path / "search.rrd"
    with RunRecording(f"save:{rrd}") as rec:
        log_search(rec, out.trail)
    r = load_rrd(rrd)
    strips = r.static("/charts/search/bars", "LineStrips2D:strips")
    radii = r.static("/charts/search/bars", "LineStrips2D:radii")
    length = [abs(s[-1][1] - s[0][1]) + 2 * rad for s, rad in zip(strips, radii, strict=True)]
    assert len(strips) == len(out.trail)
    assert min(length) > 0.1 * max(length)  # chi2/dof 1.2 next to 300: a bar, not a line
    labels = r.labels("/charts/search/labels")
    assert {"0 model3", "tied, not taken", "removed (proxy) = final", "1.2", "300"} <= set(labels)
    path = np.asarray(r.static("/charts/search/path", "LineStrips2D:strips")[0], float)
    assert len(path) == 5  # start, +warmup, +nonlin2, -warmup, -temp_bias2: not the side branches
    assert path[3, 1] > path[0, 1]  # lower on screen: smaller chi2/dof
    colors = r.static("/charts/search/bars", "LineStrips2D:colors")
    assert len(set(colors)) == 2  # no ladder given: grey on the path, darker grey for side branches


def test_search_labels_stay_under_the_viewers_limit(tmp_path):
    """The Rerun viewer draws no label of an entity holding more than 30: a long search's labels
    (two per row, the ticks, two values per bar) come in groups, each under the limit."""
    from accellog.flows.workbench_trail import TrailStep

    trail = [
        TrailStep(
            k, f"+e{k}", "+".join(["model3", *[f"e{j}" for j in range(k)]]), "kept", score=100.0 / (k + 1)
        )
        for k in range(20)
    ]
    rrd = tmp_path / "long.rrd"
    with RunRecording(f"save:{rrd}") as rec:
        log_search(rec, trail)
    r = load_rrd(rrd)
    groups = [e for e in r.entities if e.startswith("/charts/search/labels/")]
    assert groups and all(len(r.static(e, "Points2D:labels")) <= 30 for e in groups)
    assert {"0 +e0", "19 +e19", "100"} <= set(r.labels("/charts/search/labels"))
