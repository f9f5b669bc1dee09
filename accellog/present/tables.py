"""Rich tables and JSON helpers for the batch stages (the seed's three tables and more).

- `params_table`: every parameter with value +- 1-sigma and unit, plus fit statistics;
- `static_means_table` (seed Table 4): mean residual of the calibrated static test per axis with
  +- its autocorrelation-aware standard error (m/s^2), chi2 against the noise;
- `displacement_table` (seed Table 5): integrated displacement at a time per model (m);
- `drift_table` (the seed's final table): before / after the drift model, and the q with +-.
- `ladder_table`: the model ladder (accellog.calibrate.diagnosis.ladder.LadderRow rows).
Every column names its unit.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from rich.console import Console
from rich.table import Table

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.calfile.drift_model import DriftModel
from accellog.core.jsonio import dumps

if TYPE_CHECKING:
    from accellog.calibrate.diagnosis.ladder import LadderRow
    from accellog.navigate.evaluate import Evaluation, PoseEvaluation

AXES = ("x", "y", "z")


def fmt_pm(value: float, sigma: float, digits: int = 4) -> str:
    """'v +- s' with s to 2 significant digits and v to the same decimal place (g-style fallback)."""
    if not np.isfinite(sigma) or sigma <= 0:
        return f"{value:.{digits}g}"
    dec = max(0, -int(np.floor(np.log10(sigma))) + 1)
    if dec > 12:
        return f"{value:.6g} ± {sigma:.2g}"
    return f"{value:.{dec}f} ± {sigma:.{dec}f}"


def params_table(cal: Calibration, title: str | None = None) -> Table:
    """Parameters of a calibration: name, value +- 1-sigma, unit; caption with fit statistics."""
    t = Table(title=title or f"calibration {cal.model_spec.get('name', '')} (terms: {', '.join(cal.terms)})")
    t.add_column("parameter")
    t.add_column("value ± 1σ", justify="right")
    t.add_column("unit")
    for n, v, s, u in zip(cal.param_names, cal.theta, cal.sigma, cal.param_units, strict=True):
        t.add_row(n, fmt_pm(float(v), float(s)), u)
    f = cal.fit
    parts = []
    if f.rms_g is not None:
        parts.append(f"residual RMS {f.rms_g * 1000:.4g} mg")
    if f.chi2_dof is not None:
        parts.append(f"chi2/dof {f.chi2_dof:.4g} (dof {f.dof})")
    parts.append("weighted" if f.weighted else "unweighted")
    parts.append(
        f"truth {cal.truth_g:.6g} g/pose ({cal.gravity_convention}), g_local {cal.local_gravity_mps2} m/s²"
    )
    t.caption = "; ".join(parts)
    return t


def static_means_table(
    evals: Sequence[Evaluation], title: str = "static test: mean residual after calibration"
) -> Table:
    """Seed Table 4: per row, mean of (calibrated - expected) per axis +- sem (m/s^2)."""
    t = Table(title=title)
    t.add_column("model")
    for ax in AXES:
        t.add_column(f"{ax} mean (m/s²)", justify="right")
    t.add_column("RMS (m/s²)", justify="right")
    t.add_column("χ² noise (dof 3)", justify="right")
    for ev in evals:
        t.add_row(
            ev.label,
            *(fmt_pm(float(m), float(s)) for m, s in zip(ev.mean_resid_mps2, ev.sem_mps2, strict=True)),
            f"{ev.rms_mps2:.4g}",
            f"{ev.chi2_noise:.3g}",
        )
    if evals:
        t.caption = f"{evals[0].session}: {evals[0].n} samples, {evals[0].duration_s:.1f} s; ± = autocorrelation-aware sem"
    return t


def displacement_table(
    evals: Sequence[Evaluation], at_s: float = 60.0, drift: bool = False, title: str | None = None
) -> Table:
    """Seed Table 5: integrated displacement (m) at at_s per row (after the drift model if drift)."""
    t = Table(title=title or f"integrated displacement at {at_s:g} s")
    t.add_column("model")
    for ax in AXES:
        t.add_column(f"{ax} (m)", justify="right")
    t.add_column("t used (s)", justify="right")
    for ev in evals:
        i = int(np.argmin(np.abs(ev.times_s - at_s)))
        d = ev.disp_at(at_s, drift=drift)
        t.add_row(
            ev.label + (" + drift model" if drift and ev.drift_applied else ""),
            *(f"{v:.4g}" for v in d),
            f"{ev.t_used_s[i]:.2f}",
        )
    return t


def drift_table(
    rows: Sequence[tuple[str, np.ndarray]], t_end_s: float, model: DriftModel | None = None
) -> tuple[Table, Table | None]:
    """The seed's final table (label, displacement (3,) m at t_end_s) and the drift q +- 1-sigma."""
    t = Table(title=f"displacement of the static test at {t_end_s:.2f} s")
    t.add_column("calibration")
    for ax in AXES:
        t.add_column(f"{ax} (m)", justify="right")
    for label, d in rows:
        t.add_row(label, *(f"{v:.4g}" for v in d))
    if model is None:
        return t, None
    q = Table(title="drift model d' = d + ½ q2 t² + q1 t + q0")
    q.add_column("axis")
    q.add_column("q0 (m)", justify="right")
    q.add_column("q1 (m/s)", justify="right")
    q.add_column("q2 (m/s²)", justify="right")
    q.add_column("RMS resid (m)", justify="right")
    for i, ax in enumerate(AXES):
        q.add_row(
            ax,
            *(fmt_pm(float(model.q[i, k]), float(model.sigma[i, k])) for k in range(3)),
            f"{model.rms_residual_m[i]:.3g}",
        )
    q.caption = "limits: " + model.limits
    return t, q


class _HeadersWrapFirst(Table):
    """A table that, when too wide for the terminal, wraps the headers of its number columns (each
    down to its widest cell or header word: ``caps``) and collapses the padding between columns
    before rich narrows the other columns."""

    def __init__(self, *args, **kw) -> None:
        super().__init__(*args, **kw)
        self.caps: list = []

    def __rich_console__(self, console, options):
        wide = self.__rich_measure__(console, options).maximum > options.max_width
        for column, cap in self.caps:
            column.max_width = cap if wide else None
        self.collapse_padding = wide  # one space between columns, not two
        yield from super().__rich_console__(console, options)


def ladder_table(rows: Sequence[LadderRow], title: str = "model ladder") -> Table:
    """The one table of the model ladder: model, params, chi2/dof and RMS (mg) on the calibration
    data; held-out RMS and noise floor (mg), held-out chi2/dof and static-test drift (m) when any row
    has them; the number of warnings per model in the caption (its columns fit 80 characters)."""

    def mg(v: float | None) -> str:
        return "-" if v is None else f"{v * 1000:.3g}"

    def num(v: float | None) -> str:
        return "-" if v is None else f"{v:.3g}"

    held = any(r.heldout_rms_g is not None for r in rows)
    chi = any(getattr(r, "heldout_chi2_dof", None) is not None for r in rows)
    ats = sorted({r.drift_at_s for r in rows if r.drift_at_s is not None})
    cols = ["model", "params", "χ²/dof (fit)", "RMS (mg)"]
    cols += ["held-out RMS (mg)", "noise floor (mg)"] if held else []
    cols += ["held-out χ²/dof"] if chi else []
    cols += [f"{a:g} s drift (m)" for a in ats]
    body = []
    for r in rows:
        # a narrow terminal wraps the model at its terms ("model3 + temp_bias +" / "temp_scale"), never inside one
        cells = [r.model.replace("+", " + "), str(r.n_params), num(r.chi2_dof), mg(r.rms_g)]
        cells += [mg(r.heldout_rms_g), mg(r.heldout_noise_g)] if held else []
        cells += [num(r.heldout_chi2_dof)] if chi else []
        cells += [num(r.drift_m) if r.drift_at_s == a else "-" for a in ats]
        body.append(cells)
    t = _HeadersWrapFirst(title=title)
    for k, c in enumerate(cols):  # a number or a term never is split (min_width)
        if c == "model":
            term = max((len(w) for b in body for w in b[k].split()), default=1) + 2  # "temp_bias +"
            t.add_column(c, min_width=term, overflow="fold")
            continue
        widest = max((len(b[k]) for b in body), default=1)
        t.add_column(c, justify="right", min_width=widest, overflow="fold")
        t.caps.append((t.columns[-1], max(widest, *(len(w) for w in c.split()))))
    for cells in body:
        t.add_row(*cells)
    warned = [f"{r.model.replace('+', ' + ')} {len(r.warnings)}" for r in rows if r.warnings]
    if warned:
        t.caption = "warnings (the fit prints them): " + ", ".join(warned)
    return t


def pose_eval_table(pe: PoseEvaluation) -> Table:
    """Mean residual per pose (mg) +- sem of a multi-pose evaluation."""
    t = Table(title=f"{pe.label} on {pe.session}: residual per pose")
    t.add_column("pose")
    for ax in AXES:
        t.add_column(f"{ax} (mg)", justify="right")
    for n, m, s in zip(pe.pose_names, pe.mean_resid_g, pe.sem_g, strict=True):
        t.add_row(n, *(fmt_pm(float(a) * 1000, float(b) * 1000) for a, b in zip(m, s, strict=True)))
    t.caption = f"RMS {pe.rms_g * 1000:.4g} mg, chi2/dof {pe.chi2 / max(pe.dof, 1):.3g}"
    return t


def pass_eval_table(pe: PoseEvaluation) -> Table | None:
    """Mean residual per visit of a pose (mg) +- sem with span, temperature and chi2/dof; None when
    every pose was visited once and no pose trends (the pose table says it all)."""
    if len(pe.passes) <= len({p.pose for p in pe.passes}) and not pe.flags:
        return None
    t = Table(title=f"{pe.label} on {pe.session}: residual per pass (visit of a pose)")
    for c in ("pose", "visit", "t (s)", "T (degC)", *(f"{ax} (mg)" for ax in AXES), "chi2/dof"):
        t.add_column(c, justify="left" if c == "pose" else "right")
    for p in pe.passes:
        temp = "-" if p.temp_min_degC is None else f"{p.temp_min_degC:.1f}-{p.temp_max_degC:.1f}"
        t.add_row(p.pose, str(p.visit), f"{p.start_s:.0f}-{p.end_s:.0f}", temp,
                  *(fmt_pm(float(a) * 1000, float(b) * 1000) for a, b in zip(p.mean_resid_g, p.sem_g, strict=True)),
                  f"{p.chi2_dof:.3g}")  # fmt: skip
    return t


def handheld_eval_table(h) -> Table:
    """Gravity-norm residual |f| - g (mg) +- sem per detected static interval of a hand-held session."""
    t = Table(title=f"{h.label} on {h.session}: |f| - g per detected static interval")
    for c in ("interval", "t (s)", "up (sensor)", "windows", "|f| - g (mg)", "chi2/dof"):
        t.add_column(c, justify="right")
    for k, r in enumerate(h.rows()):
        up = " ".join(f"{v:+.2f}" for v in r["up_sensor"])
        t.add_row(str(k), f"{r['start_s']:.1f}-{r['end_s']:.1f}", up, str(r["n_windows"]),
                  fmt_pm(1e3 * r["mean_norm_residual_g"], 1e3 * r["sem_g"]), f"{r['chi2_dof']:.3g}")  # fmt: skip
    d = h.to_dict()
    t.caption = f"RMS {d['rms_g'] * 1e3:.4g} mg, chi2/dof {d['chi2_dof']:.3g} ({d['dof']} windows)"
    return t


def print_tables(tables: Sequence[Table | None], console: Console | None = None) -> None:
    console = console or Console()
    for t in tables:
        if t is not None:
            console.print(t)


def json_text(data: Any) -> str:
    """Strict JSON text of results (numpy arrays as lists, NaN as null)."""
    return dumps(data)


def _fmt_m(x: float, unit: str = "m") -> str:
    return "-" if x != x else f"{x:.3g} {unit}"


def track_table(title: str, runs, zupt: bool) -> Table:
    """Final and RMS position error per track (and without ZUPT, with the number of stops)."""
    table = Table(title=title)
    for c in ("calibration", "final error", "RMS error", "% of path"):
        table.add_column(c, justify="left" if c == "calibration" else "right")
    if zupt:
        table.add_column("final w/o ZUPT", justify="right")
        table.add_column("stops", justify="right")
    for r in runs:
        e = r.error
        row = [r.name, _fmt_m(e.final_error_m), _fmt_m(e.rms_error_m), f"{e.final_error_pct_of_path:.2g}"]
        if zupt:
            row += [_fmt_m(r.error_without_zupt.final_error_m), str(e.zupt_stops)]
        table.add_row(*row)
    return table


def segment_table(title: str, stats) -> Table:
    """Per-pose statistics: time span, samples, mean +- sem per axis (g), autocorrelation time, temperature."""
    t = Table(title=title)
    t.add_column("pose")
    t.add_column("t (s)")
    t.add_column("n", justify="right")
    for ax in "xyz":
        t.add_column(f"{ax} mean ± sem (g)", justify="right")
    t.add_column("tau (samples)", justify="right")
    t.add_column("T (degC)", justify="right")
    for p in stats:
        t.add_row(
            p.name,
            f"{p.start_s:.1f}-{p.end_s:.1f}",
            str(p.n),
            *(fmt_pm(float(m), float(s)) for m, s in zip(p.mean_g, p.sem_g, strict=True)),
            "/".join(f"{x:.1f}" for x in p.tau_samples),
            "-" if p.temp_degC is None else f"{p.temp_degC:.2f}",
        )
    return t


def pose_eval_summary(pes, at_s: float) -> list[str]:
    """One line per evaluation: RMS, chi2/dof and the worst hold's displacement at at_s (m)."""
    lines = []
    for p in pes:
        d = p.to_dict()[f"displacement_{at_s:g}s_m"]
        lines.append(
            f"{p.label}: RMS {p.rms_g * p.mps2_per_unit:.4g} m/s^2, chi2/dof {p.chi2 / max(p.dof, 1):.3g}; "
            f"worst hold displacement at {at_s:g} s (from rest, extrapolated) "
            + ", ".join(f"{a} {v:+.3g} m" for a, v in zip("xyz", d, strict=True))
        )
    return lines


def replay_table(res, title: str) -> Table:
    """Final displacement (m) of each replayed track and whether a drift model was applied."""
    t = Table(title=title)
    for c in ("track", "x (m)", "y (m)", "z (m)", "|d| (m)", "drift model"):
        t.add_column(c, justify="left" if c in ("track", "drift model") else "right")
    for tr in res.tracks:
        d = tr.final_m
        t.add_row(
            tr.label,
            f"{d[0]:+.3f}",
            f"{d[1]:+.3f}",
            f"{d[2]:+.3f}",
            f"{np.linalg.norm(d):.3f}",
            "applied" if tr.disp_end_drift_m is not None else "-",
        )
    return t
