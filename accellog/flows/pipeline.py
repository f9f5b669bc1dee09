"""Pipelines declared in TOML files: `run_pipeline(toml, inputs)` -> PipelineResult (tables(), to_dict()).

Pipeline file (copy one of pipelines/*.toml and edit it): tables [pipeline] (name, description,
inputs = roles of the SESSION arguments in order), [segment], [fit], [evaluate], [evaluate_poses],
[drift], [report]; unknown tables or keys are refused with the file and line.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import tomllib

from accellog.calibrate.calfile.calibration import (
    GRAVITY_CONVENTIONS,
    read_text,
    source_entry,
    write_json_atomic,
)
from accellog.calibrate.model.effects import load_effects_file
from accellog.core.errors import InputError, ModelError, did_you_mean
from accellog.core.jsonio import JsonResult
from accellog.core.ranges import check_option
from accellog.core.session import ObsTable, Session
from accellog.core.textin import toml_loads
from accellog.flows.stages import (
    DriftOutcome,
    FitOutcome,
    load_input,
    run_drift,
    run_evaluate,
    run_fit,
)
from accellog.navigate.evaluate import Evaluation, PoseEvaluation, evaluate_poses
from accellog.present import tables as report
from accellog.present import views
from accellog.present.rrd.offload import open_recording
from accellog.store.atomic import inside

if TYPE_CHECKING:
    from accellog.calibrate.diagnosis.ladder import LadderRow

# ------------------------------------------------------------------------------------------ pipelines

_SCHEMA: dict[str, dict[str, type | tuple[type, ...]]] = {
    "pipeline": {"name": str, "description": str, "inputs": list},
    "segment": {"window_s": (int, float), "trim_s": (int, float), "n_per_pose": int},
    "fit": {
        "input": str,
        "models": list,
        "weighted": bool,
        "gravity": str,
        "local_gravity_mps2": (int, float),
        "orientation_free": bool,
    },
    "evaluate": {
        "input": str,
        "models": list,
        "include_raw": bool,
        "times_s": list,
        "until_s": (int, float),
        "max_samples": int,
    },
    "evaluate_poses": {"input": str, "models": list},
    "drift": {
        "model": str,
        "fit_input": str,
        "apply_input": str,
        "fit_until_s": (int, float),
        "fit_max_samples": int,
        "apply_until_s": (int, float),
        "apply_max_samples": int,
    },
    "report": {"at_s": (int, float), "output_dir": str},
}
_REQUIRED = {"pipeline": ("name", "inputs"), "fit": ("input", "models")}
_RANGES = {  # (table, key) -> the command-line option whose range (core.ranges) holds for it
    ("segment", "window_s"): "--window-s",
    ("segment", "trim_s"): "--trim-s",
    ("fit", "local_gravity_mps2"): "--local-gravity",
    ("evaluate", "times_s"): "--at-s",
    ("evaluate", "until_s"): "--until-s",
    ("evaluate", "max_samples"): "--max-samples",
    ("drift", "fit_until_s"): "--until-s",
    ("drift", "apply_until_s"): "--until-s",
    ("drift", "fit_max_samples"): "--max-samples",
    ("drift", "apply_max_samples"): "--max-samples",
    ("report", "at_s"): "--at-s",
}


def _line_of(text: str, table: str, key: str | None = None) -> int:
    """1-based line of [table] (or of key = inside it), 0 if not found."""
    lines = text.splitlines()
    start = 0
    for i, ln in enumerate(lines):
        if re.match(rf"^\s*\[{re.escape(table)}\]\s*(#.*)?$", ln):
            start = i
            if key is None:
                return i + 1
            break
    if key is None:
        return 0
    for i in range(start, len(lines)):
        if re.match(rf"^\s*{re.escape(key)}\s*=", lines[i]):
            return i + 1
    return 0


def load_pipeline(path: str | os.PathLike) -> dict:
    """Parse and validate a pipeline TOML file; InputError naming the file:line and key."""
    p = Path(path)
    text = read_text(p, "pipeline file", kind="TOML")
    try:
        spec = toml_loads(text, str(p))
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        line = m.group(1) if m else str(max(len(text.splitlines()), 1))  # 'at end of document'
        raise InputError(f"not valid TOML: {exc}", where=f"{p}:{line}") from None
    _check_schema(spec, text, p)
    _check_references(spec, text, p)
    spec["_path"] = str(p)
    return spec


def _check_schema(spec: dict, text: str, p: Path) -> None:
    """Known tables and keys of the right types; required keys present."""
    for table, body in spec.items():
        if table not in _SCHEMA:
            raise InputError(
                f"unknown stage [{table}]{did_you_mean(table, _SCHEMA)} (known: {', '.join(_SCHEMA)})",
                where=f"{p}:{_line_of(text, table) or 1}",
            )
        if not isinstance(body, dict):
            raise InputError(
                f"'{table}' must be a table [{table}]", where=f"{p}:{_line_of(text, table, None) or 1}"
            )
        for key, val in body.items():
            if key == "effects_file":
                raise InputError(
                    f"'{table}.effects_file': a pipeline file names no code to run; remove the key and "
                    "pass --effects-file F.py on the command line",
                    where=f"{p}:{_line_of(text, table, key) or 1}",
                )
            if key not in _SCHEMA[table]:
                raise InputError(
                    f"unknown key '{table}.{key}'{did_you_mean(key, _SCHEMA[table])} (known: {', '.join(_SCHEMA[table])})",
                    where=f"{p}:{_line_of(text, table, key) or 1}",
                )
            want = _SCHEMA[table][key]
            ok = isinstance(val, want) and not (isinstance(val, bool) and want in ((int, float), int))
            if not ok:
                tn = want.__name__ if isinstance(want, type) else "number"
                raise InputError(
                    f"'{table}.{key}' must be a {tn}, got {val!r}",
                    where=f"{p}:{_line_of(text, table, key) or 1}",
                )
            if any(
                isinstance(v, float) and not math.isfinite(v)
                for v in (val if isinstance(val, list) else [val])
            ):
                raise InputError(
                    f"'{table}.{key}' = {val!r} must be finite (no nan or inf)",
                    where=f"{p}:{_line_of(text, table, key) or 1}",
                )
            if (table, key) in _RANGES:
                try:
                    check_option(_RANGES[table, key], val)
                except InputError as exc:  # "--window-s: 1e+308 is out of range: ..." said of the key
                    raise InputError(
                        f"'{table}.{key}': {str(exc).split(': ', 1)[-1]}",
                        where=f"{p}:{_line_of(text, table, key) or 1}",
                    ) from None
    for table, keys in _REQUIRED.items():
        for k in keys:
            if k not in spec.get(table, {}):
                raise InputError(f"missing '{table}.{k}'", where=str(p))


def _check_references(spec: dict, text: str, p: Path) -> None:
    """Roles, model names, times and the gravity convention refer to what the file declares."""
    roles = spec["pipeline"]["inputs"]
    if not roles or not all(isinstance(r, str) for r in roles) or len(set(roles)) != len(roles):
        raise InputError(
            "'pipeline.inputs' must list distinct role names",
            where=f"{p}:{_line_of(text, 'pipeline', 'inputs')}",
        )
    for table, key in (
        ("fit", "input"),
        ("evaluate", "input"),
        ("evaluate_poses", "input"),
        ("drift", "fit_input"),
        ("drift", "apply_input"),
    ):
        role = spec.get(table, {}).get(key)
        if role is not None and role not in roles:
            raise InputError(
                f"'{table}.{key}' = {role!r} is not one of pipeline.inputs {roles}",
                where=f"{p}:{_line_of(text, table, key)}",
            )
    models = spec["fit"]["models"]
    if not models or not all(isinstance(m, str) for m in models):
        raise InputError(
            "'fit.models' must be a list of model names", where=f"{p}:{_line_of(text, 'fit', 'models')}"
        )
    for table in ("evaluate", "evaluate_poses"):
        for m in spec.get(table, {}).get("models", []):
            if m not in models:
                raise InputError(
                    f"'{table}.models' names {m!r}, not in fit.models",
                    where=f"{p}:{_line_of(text, table, 'models')}",
                )
    dm = spec.get("drift", {}).get("model")
    if dm is not None and dm not in models:
        raise InputError(
            f"'drift.model' = {dm!r} is not in fit.models", where=f"{p}:{_line_of(text, 'drift', 'model')}"
        )
    ts = spec.get("evaluate", {}).get("times_s")
    if ts is not None and not (
        ts and all(isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0 for x in ts)
    ):
        raise InputError(
            f"'evaluate.times_s' must be a non-empty list of times > 0 (s), got {ts!r}",
            where=f"{p}:{_line_of(text, 'evaluate', 'times_s')}",
        )
    od = spec.get("report", {}).get("output_dir")
    if od is not None:  # a data file never writes outside its own folder
        inside(p.parent, od, f"{p}:{_line_of(text, 'report', 'output_dir')}", "report.output_dir")
    gv = spec["fit"].get("gravity", "local")
    if gv not in GRAVITY_CONVENTIONS:
        raise InputError(
            f"'fit.gravity' must be 'seed' or 'local', got {gv!r}",
            where=f"{p}:{_line_of(text, 'fit', 'gravity')}",
        )


@dataclass
class PipelineResult(JsonResult):
    """Everything a pipeline run produced."""

    name: str
    inputs: dict[str, str]
    fits: dict[str, FitOutcome] = field(default_factory=dict)
    evaluations: list[Evaluation] = field(default_factory=list)
    pose_evaluations: list[PoseEvaluation] = field(default_factory=list)
    drift: DriftOutcome | None = None
    drift_evaluations: list[Evaluation] = field(default_factory=list)
    at_s: float = 60.0
    written: list[str] = field(default_factory=list)

    def ladder(self) -> list[LadderRow]:
        """One ladder row per fitted model (named as in the pipeline file)."""
        from accellog.calibrate.diagnosis.ladder import ladder_row

        return [ladder_row(fo.fit, fit=fo, model=name) for name, fo in self.fits.items()]

    def tables(self) -> list:

        out: list = [report.ladder_table(self.ladder())]
        for fo in self.fits.values():
            out.append(report.params_table(fo.cal))
        if self.evaluations:
            out.append(report.static_means_table(self.evaluations))
            out.append(report.displacement_table(self.evaluations, at_s=self.at_s))
        out += [report.pose_eval_table(pe) for pe in self.pose_evaluations]
        if self.drift is not None and self.drift_evaluations:
            rows = [(ev.label, ev.disp_end_m) for ev in self.drift_evaluations]
            last = self.drift_evaluations[-1]
            if last.drift_applied and last.disp_end_drift_m is not None:
                rows.append((last.label + " + drift model", last.disp_end_drift_m))
            t, q = report.drift_table(rows, last.t_end_s, self.drift.drift)
            out += [t, q]
        return out

    def to_dict(self) -> dict:
        d: dict[str, Any] = {
            "pipeline": self.name,
            "inputs": self.inputs,
            "fits": {k: v.to_dict() for k, v in self.fits.items()},
            "evaluations": [e.to_dict() for e in self.evaluations],
            "pose_evaluations": [e.to_dict() for e in self.pose_evaluations],
            "written": list(self.written),
        }
        if self.drift is not None:
            d["drift"] = self.drift.to_dict()
            d["drift_evaluations"] = [e.to_dict() for e in self.drift_evaluations]
        return d

    def write_rrd(self, path: str | os.PathLike) -> None:
        """Recording of every fit, the evaluations (and after the drift model) and the result tables."""

        with open_recording(f"save:{path}") as rec:
            for name, fo in self.fits.items():
                views.log_fit(rec, fo, name)
            views.log_evaluations(rec, self.evaluations)
            if self.drift_evaluations:
                views.log_evaluations(rec, self.drift_evaluations, truth_label=None)
            rec.log_document(
                "results/tables", "\n".join(views.table_markdown(t) for t in self.tables() if t is not None)
            )


class _Inputs:
    """The pipeline's input files by role, each loaded once."""

    def __init__(
        self,
        spec: dict,
        inputs: Sequence[str | os.PathLike],
        preloaded: dict[str, Session | ObsTable] | None = None,
    ) -> None:
        self.where = spec.get("_path")
        self.roles = spec["pipeline"]["inputs"]
        if len(inputs) != len(self.roles):
            raise InputError(
                f"pipeline {spec['pipeline']['name']!r} takes {len(self.roles)} inputs "
                f"({', '.join(self.roles)}), got {len(inputs)}",
                where=self.where,
            )
        self.files = {r: str(x) for r, x in zip(self.roles, inputs, strict=True)}
        self.n_per_pose = spec.get("segment", {}).get("n_per_pose")
        self.base = Path(self.where).parent if self.where else Path.cwd()
        given = preloaded or {}
        self._cache: dict[str, Session | ObsTable] = {
            r: given[f] for r, f in self.files.items() if f in given
        }

    def get(self, role: str) -> Session | ObsTable:
        if role not in self._cache:
            self._cache[role] = load_input(self.files[role], n_per_pose=self.n_per_pose)
        return self._cache[role]

    def session(self, role: str, what: str) -> Session:
        x = self.get(role)
        if isinstance(x, ObsTable):
            raise InputError(
                f"{what} needs a recorded session (samples), not a pose table / observations",
                where=str(self.files[role]),
            )
        return x


def _fit_models(spec: dict, inp: _Inputs, res: PipelineResult, ef) -> None:
    """[fit]: every model on the same observations (segmented once); `ef` the user's effects file."""
    fs, seg = spec["fit"], spec.get("segment", {})
    data = inp.get(fs["input"])
    obs = None
    for mname in fs["models"]:
        try:
            fo = run_fit(
                data,
                mname,
                effects_file=ef,
                weighted=fs.get("weighted", True),
                orientation_free=fs.get("orientation_free", False),
                gravity=fs.get("gravity", "local"),
                local_gravity_mps2=fs.get("local_gravity_mps2"),
                window_s=seg.get("window_s", 2.0),
                trim_s=seg.get("trim_s", 0.5),
                obs=obs,
            )
        except ModelError as exc:
            raise ModelError(f"model {mname!r}: {exc}", where=inp.where) from None
        path = inp.files[fs["input"]]  # the input as the pipeline's caller named it
        src = fo.cal.sources[0] if fo.cal.sources else None
        if src is None or src.path != path:  # else its SHA-256 and what a recovery kept stand
            src = dataclasses.replace(source_entry(path, (src.kind or "") if src else ""),
                                      recovered=src.recovered if src else None)  # fmt: skip
        fo.cal.sources = [src]
        obs = fo.obs
        res.fits[mname] = fo


def _evaluate(spec: dict, inp: _Inputs, res: PipelineResult) -> None:
    """[evaluate] (one static hold) and [evaluate_poses] (hold by hold)."""
    if "evaluate" in spec:
        es = spec["evaluate"]
        names = es.get("models", list(res.fits))
        res.evaluations = run_evaluate(
            inp.session(es.get("input", inp.roles[0]), "evaluate"),
            [res.fits[n].cal for n in names],
            include_raw=es.get("include_raw", True),
            times_s=es.get("times_s", (10.0, 30.0, 60.0)),
            until_s=es.get("until_s"),
            max_samples=es.get("max_samples"),
            labels=names,
        )
    if "evaluate_poses" in spec:
        ep = spec["evaluate_poses"]
        s = inp.session(ep["input"], "evaluate_poses")
        res.pose_evaluations = [evaluate_poses(s, res.fits[n].cal) for n in ep.get("models", list(res.fits))]


def _drift(spec: dict, inp: _Inputs, res: PipelineResult) -> None:
    """[drift]: fit the drift polynomial on one static session, apply it to another."""
    ds = spec["drift"]
    mname = ds.get("model", list(res.fits)[-1])
    res.drift = run_drift(
        inp.session(ds["fit_input"], "drift"),
        res.fits[mname].cal,
        until_s=ds.get("fit_until_s"),
        max_samples=ds.get("fit_max_samples"),
    )
    res.drift_evaluations = run_evaluate(
        inp.session(ds.get("apply_input", ds["fit_input"]), "drift"),
        [res.drift.cal],
        include_raw=True,
        until_s=ds.get("apply_until_s"),
        max_samples=ds.get("apply_max_samples"),
        labels=[mname],
    )


def _write_outputs(res: PipelineResult, od: Path, inputs: list) -> None:
    """cal_<model>.json per fit, cal_drift.json, results.json (each checked first, then written atomically)."""
    _prepare_output_dir(od, res, inputs)
    for mname, fo in res.fits.items():
        fo.cal.save(od / f"cal_{_safe(mname)}.json")
        res.written.append(str(od / f"cal_{_safe(mname)}.json"))
    if res.drift is not None:
        res.drift.cal.save(od / "cal_drift.json")
        res.written.append(str(od / "cal_drift.json"))
    write_json_atomic(od / "results.json", res.to_dict())
    res.written.append(str(od / "results.json"))


def run_pipeline(
    pipeline: str | os.PathLike | dict,
    inputs: Sequence[str | os.PathLike],
    *,
    output_dir: str | os.PathLike | None = None,
    preloaded: dict[str, Session | ObsTable] | None = None,
    effects_file: str | os.PathLike | None = None,
) -> PipelineResult:
    """Run a pipeline file on input files given in the order of pipeline.inputs.

    preloaded: inputs already read, by file name (str), so that they are not read again.
    effects_file: the Python file of user effects named by the user (a pipeline file names none)."""
    spec = pipeline if isinstance(pipeline, dict) else load_pipeline(pipeline)
    inp = _Inputs(spec, inputs, preloaded)
    report = spec.get("report", {})
    res = PipelineResult(
        name=spec["pipeline"]["name"], inputs=inp.files, at_s=float(report.get("at_s", 60.0))
    )
    _fit_models(spec, inp, res, load_effects_file(Path(effects_file)) if effects_file else None)
    _evaluate(spec, inp, res)
    if "drift" in spec:
        _drift(spec, inp, res)
    if output_dir or report.get("output_dir"):
        od = (
            Path(output_dir)
            if output_dir
            else inside(inp.base, report["output_dir"], str(inp.where or "pipeline"), "report.output_dir")
        )
        _write_outputs(res, od, [inp.where, *inputs])
    return res


def _prepare_output_dir(od: Path, res, inputs: list) -> None:
    """Create the output folder and check every file to be written there before writing any."""
    from accellog.store.atomic import check_outputs

    if od.exists() and not od.is_dir():
        raise InputError("output folder is an existing file", where=str(od))
    try:
        od.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the output folder: {exc.strerror or exc}", where=str(od)) from None
    names = [f"cal_{_safe(m)}.json" for m in res.fits] + (["cal_drift.json"] if res.drift else [])
    check_outputs([od / n for n in [*names, "results.json"]], inputs)


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def describe_pipeline(path: str | os.PathLike) -> str:
    """One line: name, roles and stages of a pipeline file (for --help style listings)."""
    spec = load_pipeline(path)
    stages = [k for k in spec if k not in ("pipeline", "_path")]
    return json.dumps(
        {"name": spec["pipeline"]["name"], "inputs": spec["pipeline"]["inputs"], "stages": stages}
    )
