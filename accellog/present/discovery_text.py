"""Terminal output of the discovery commands: the effect library (`effects`), a diagnosis
(`diagnose`: parameters, candidates, driver signals, verdict) and the workbench's verdict and ladder.

The results are duck-typed (accellog.flows.diagnose_run.DiagnoseOutcome,
accellog.flows.workbench.WorkbenchOutcome): present/ does not import flows/.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

WIDTH = 160
"""Columns of the text written into a file or a pipe (a log keeps whole table rows)."""


def terminal(stderr: bool = False) -> Console:
    """A console at the terminal's width, or WIDTH when the output is not a terminal."""
    stream = sys.stderr if stderr else sys.stdout
    return Console(stderr=stderr, width=None if stream.isatty() else WIDTH)


def _fmt(v, spec: str = ".3g") -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return format(v, spec)


def effects_table(rows: Sequence[dict]) -> Table:
    """The effect library (accellog.calibrate.model.effects.describe rows)."""
    t = Table(title="accellog effect library (names accepted by --add)")
    for c in ("effect", "parameters [unit]", "drivers", "meaning", "revealed by"):
        t.add_column(c, overflow="fold")
    for r in rows:
        params = (
            ", ".join(f"{p} [{u}]" for p, u in zip(r["params"], r["units"], strict=True))
            or "(none in static model)"
        )
        t.add_row(
            r["effect"],
            escape(params),
            ", ".join(r["drivers"]) or "-",
            escape(r["meaning"]),
            escape(r["reveal"]),
        )
    return t


def print_effects(rows: Sequence[dict]) -> None:
    Console(width=200).print(effects_table(rows))
    print("presets: model1 = bias; model2 = bias+scale; model3 = bias+scale+cross_axis")


def _detected_line(source: str, det) -> str:
    k = det.threshold if det.threshold is not None else "swept 2..10"
    return f"[bold]{source}[/]: no pose labels: {len(det.intervals)} static intervals detected (window {det.window_s:g} s, threshold {k})"


def params_sigma_table(fit) -> Table:
    """Parameters of a FitResult with their noise-only 1-sigma."""
    t = Table(title="parameters (1-sigma: noise-only Cramer-Rao bound)")
    for c in ("param", "value", "1-sigma", "unit"):
        t.add_column(c, justify="right" if c in ("value", "1-sigma") else "left")
    for n, v, s, u in zip(fit.param_names, fit.theta, fit.sigma, fit.param_units, strict=True):
        t.add_row(n, f"{v:.6g}", f"{s:.2g}", u)
    return t


def candidates_table(candidates: Sequence[dict]) -> Table:
    """Candidate effects of a diagnosis, ranked."""
    t = Table(title="candidate effects (model + effect; OOS = held-out or blocked validation)")
    cols = ("#", "effect", "ident.", "signif.", "chi2/dof", "dBIC", "CV chi2/eq", "OOS chi2/eq", "p")
    for name in cols:
        t.add_column(name, no_wrap=True)  # a number is never split over two lines
    t.add_column("reason / what to record", overflow="fold", ratio=1)
    first_with: dict[str, str] = {}  # reason -> the first effect that gave it (said once)
    for c in candidates:
        reason = c.get("reason", "")
        said = first_with.setdefault(reason, c["effect"]) if reason else c["effect"]
        t.add_row(
            str(c["rank"]),
            c["effect"],
            "yes" if c["identifiable"] else "no",
            "YES" if c.get("significant") else "",
            _fmt(c.get("chi2_dof")),
            _fmt(c.get("delta_bic"), ".1f"),
            _fmt(c.get("cv_chi2_per_eq")),
            _fmt(c.get("oos_chi2_per_eq")),
            _fmt(c.get("p_value"), ".2g"),
            escape(reason if said == c["effect"] else f"as {said}"),
        )
    return t


def signals_table(signals: Sequence[dict], top: int = 10) -> Table:
    """Residuals against driver signals (the `top` strongest)."""
    t = Table(title="residuals vs driver signals (top 10; dchi2 = drop if added as a term on that axis)")
    for c in ("signal", "axis", "corr", "partial R^2", "dchi2", "p"):
        t.add_column(c)
    for s in signals[:top]:
        t.add_row(
            s["signal"] + (" *" if s["significant"] else ""),
            s["axis"],
            f"{s['correlation']:+.2f}",
            f"{s['partial_r2']:.3f}",
            f"{s['delta_chi2']:.3g}",
            f"{s['p_value']:.2g}",
        )
    return t


def print_diagnosis(d, source: str, con: Console | None = None) -> None:
    """A Diagnosis: parameters, out-of-sample evidence, candidates, driver signals, verdict, advice."""
    con = con or terminal()
    f = d.fit
    con.print(f"[bold]{source}[/]: {f.n_obs} windows, model {d.model.name} ({d.model.n_params} params)")
    con.print(params_sigma_table(f))
    if d.choice is not None:
        con.print(
            f"out-of-sample evidence ({d.choice.evidence}): base chi2/eq {d.choice.base_score.chi2_per_eq:.3g}; "
            + escape(d.choice.reason)
        )
    con.print(candidates_table(d.candidates))
    con.print(signals_table(d.driver_signals))
    con.print(("[bold red]MISSING[/] " if d.missing else "[bold green]OK[/] ") + escape(d.verdict))
    for a in d.advice:
        con.print(f"  - {escape(a)}")


def print_diagnose_outcome(out) -> None:
    """diagnose's terminal output (a DiagnoseOutcome)."""
    if out.detection is not None:
        terminal().print(_detected_line(out.session, out.detection))
    print_diagnosis(out.diagnosis, out.session)


def step_printer(con: Console) -> Callable[[object], None]:
    """Progress of the workbench loop: one line per step (its out-of-sample choice or verdict)."""
    from accellog.calibrate.diagnosis.diagnose import Diagnosis

    def show(d: object) -> None:
        if not isinstance(d, Diagnosis):
            raise TypeError(f"a workbench step is a Diagnosis, not {type(d).__name__}")
        con.print(f"step {d.model.name}: {escape(d.choice.reason if d.choice else d.verdict)}")

    return show


def print_notes(notes: Sequence[str]) -> None:
    """Remarks about the inputs, one 'note:' line each on stderr."""
    for n in notes:
        Console(stderr=True).print(f"note: {escape(n)}")


def ladder_table(ladder, title: str) -> Table:
    """accellog.present.tables.ladder_table, imported when a ladder is drawn: the table module loads
    calibrate/ and navigate/ (~70 ms), which `accellog effects` does not need (start-up, #9)."""
    from accellog.present.tables import ladder_table as table

    return table(ladder, title=title)


TRAIL_STATUS = {
    "start": "start",
    "kept": "kept",
    "dropped": "added, dropped later",
    "tied": "tied, not taken",
    "rejected": "rejected",
    "backward": "removed (backward step)",
    "proxy": "removed (proxy)",
}
"""How the search trail's statuses (accellog.flows.workbench_trail) read in the text and the .rrd."""
BAR_CELLS = 24


def log_bars(values: Sequence[float | None], cells: int = BAR_CELLS) -> list[str]:
    """Text bars on a log scale: from a floor a decade below the smallest value (so a value near 1
    still has a bar) to the largest, `cells` characters; '' where there is no value.

        n(v) = 1 + (cells - 1) (log10 v - floor) / (log10 max - floor),  floor = floor(log10 min) - 1
    """
    ok = [float(v) for v in values if v is not None and np.isfinite(v) and v > 0]
    if not ok:
        return ["" for _ in values]
    floor = np.floor(np.log10(min(ok))) - 1.0
    span = max(np.log10(max(ok)) - floor, 1e-12)
    out = []
    for v in values:
        if v is None or not np.isfinite(v) or v <= 0:
            out.append("")
            continue
        out.append("█" * round(1 + (cells - 1) * (np.log10(v) - floor) / span))
    return out


NARROW = 120
"""A terminal narrower than this (columns) gets the search's reasons as lines under its table."""


def search_table(trail, norm: str = "", width: int = WIDTH) -> Table:
    """Every model the workbench's search tried (TrailStep rows, in order): the change, what became
    of it, its held-out residual on the common yardstick (chi2/dof, RMS in mg) with a log-scale bar
    (the falling curve), and why (narrower than NARROW: shorter bars, no why: search_reasons)."""
    narrow = width < NARROW
    held = any(r.heldout is not None for r in trail)
    what = f"held-out {norm}residual" if held else f"out-of-sample {norm}chi2/eq (no held-out session)"
    t = Table(
        title=f"the search, step by step: {what} of every model tried" + (" (one yardstick)" if held else "")
    )
    t.add_column("step", justify="right", no_wrap=True)
    t.add_column("change", justify="left", no_wrap=True)
    t.add_column("what became of it", justify="left", no_wrap=True)
    if held:
        t.add_column("held-out χ²/dof", justify="right", no_wrap=True)
        t.add_column("held-out RMS (mg)", justify="right", no_wrap=True)
    else:
        t.add_column("OOS χ²/eq", justify="right", no_wrap=True)
    t.add_column("log scale", no_wrap=True)
    if not narrow:
        t.add_column("why", overflow="fold", ratio=1)
    if narrow:  # headers wrap at their words, numbers never
        for c in t.columns[1:-1]:
            c.no_wrap = False
    vals = [r.heldout_chi2_dof if held else r.score for r in trail]
    for r, v, bar in zip(trail, vals, log_bars(vals, BAR_CELLS // 2 if narrow else BAR_CELLS), strict=True):
        status = TRAIL_STATUS.get(r.status, r.status) + (" = final" if r.final else "")
        style = "bold green" if r.final else ("dim" if not r.on_path else "")
        nums = [_fmt(v), _fmt(r.heldout_rms_mg)] if held else [_fmt(v)]
        t.add_row(
            str(r.step),
            escape(r.change),
            status,
            *nums,
            bar,
            *([] if narrow else [escape(r.why)]),
            style=style,
        )
    return t


def print_search(trail, con: Console, norm: str = "") -> None:
    """The search table at the console's width; on a narrow terminal its reasons follow as lines."""
    con.print(search_table(trail, norm, width=con.width))
    if con.width < NARROW:
        for r in trail:
            if r.why:
                con.print(f"  {r.step} {escape(r.change)}: {escape(r.why)}")


def print_workbench(out, con: Console) -> None:
    """The workbench's verdict, advice, the search trail and the ladder (a WorkbenchOutcome)."""
    if out.handheld:
        _print_handheld(out, con)
    else:
        found = out.found
        con.print(("[bold green]OK[/] " if out.ok else "[bold red]CHECK[/] ") + escape(found.verdict))
        for a in found.advice:
            con.print(f"advice: {escape(a)}")
        if found.trail:
            print_search(found.trail, con)
        con.print(ladder_table(out.ladder, title="watch the error fall: each step of model building"))
    loso = out.loso_dict()
    if loso is not None:
        con.print(loso_table(loso))
    if out.output is not None:
        con.print(f"wrote {out.output} ({out.found.final_model})")


def loso_table(loso: dict) -> Table:
    """Leave one session out: held-out chi2/dof of each session (fit to the others) per ladder step."""
    from pathlib import Path

    t = Table(title="leave one session out: held-out chi2/dof of each session, fitted on the others")
    t.add_column("model")
    for s in loso["sessions"]:
        t.add_column(Path(s).name, justify="right")
    for step in loso["steps"]:
        t.add_row(step["model"], *(_fmt(v) for v in step["heldout_chi2_dof"]))
    return t


def _print_handheld(out, con: Console) -> None:
    found = out.found
    con.print(_detected_line(out.session, found.detection) + "; judged on the gravity norm")
    for d in found.diagnoses:
        con.print(f"step {escape(d.verdict)}")
        if d.choice is not None:
            con.print(f"  held-out norm ({d.choice.evidence}): {escape(d.choice.reason)}")
    con.print(("[bold green]OK[/] " if out.ok else "[bold red]CHECK[/] ") + escape(found.verdict))
    for a in found.advice:
        con.print(f"advice: {escape(a)}")
    for a in found.cannot_identify:
        con.print(f"cannot identify: {escape(a)}")
    if found.trail:
        print_search(found.trail, con, norm="gravity-norm ")
    con.print(
        ladder_table(out.ladder, title="hand-held: each step of model building (gravity-norm residual)")
    )
