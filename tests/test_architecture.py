"""The package's shape: layers import one way only; modules stay small enough to read."""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

from importlinter.cli import lint_imports

PKG = Path(__file__).resolve().parents[1] / "accellog"
ROOT = PKG.parent


def test_layers_contract_is_kept(monkeypatch):
    """import-linter's layers contract in pyproject.toml (cli > flows > present > ... > core)."""
    monkeypatch.chdir(ROOT)
    assert lint_imports(no_cache=True) == 0


def test_no_relative_imports():
    """Absolute imports only, so every module's layer is read off its import lines."""
    rel = [
        f"{p.relative_to(ROOT)}:{n.lineno}"
        for p in PKG.rglob("*.py")
        for n in ast.walk(ast.parse(p.read_text()))
        if isinstance(n, ast.ImportFrom) and n.level
    ]
    assert rel == []


def test_no_module_imports_another_modules_private_name():
    """A name with a leading underscore is private to its module: none is imported elsewhere."""
    found = [
        f"{p.relative_to(ROOT)}:{n.lineno} {n.module}.{a.name}"
        for p in PKG.rglob("*.py")
        for n in ast.walk(ast.parse(p.read_text()))
        if isinstance(n, ast.ImportFrom) and (n.module or "").startswith("accellog")
        for a in n.names
        if a.name.startswith("_") and not a.name.startswith("__")
    ]
    assert found == []


def test_calibrate_is_laid_out_in_rooms_without_circles():
    """calibrate/ holds rooms (observe, model, calfile, diagnosis, gyro, noise, mag), no loose
    modules but the deprecated effects-file path (effects.py: a re-export of model/effects.py), and no
    two of its modules import each other (also inside functions)."""
    cal = PKG / "calibrate"
    assert sorted(p.name for p in cal.glob("*.py")) == ["__init__.py", "effects.py"]
    shim = ast.parse((cal / "effects.py").read_text())
    assert {n.module for n in shim.body if isinstance(n, ast.ImportFrom)} == {
        "__future__", "accellog.calibrate.model.effects",
    }  # fmt: skip
    assert not [n for n in shim.body if isinstance(n, ast.FunctionDef | ast.ClassDef)]
    assert {p.name for p in cal.iterdir() if p.is_dir() and p.name != "__pycache__"} == {
        "observe", "model", "calfile", "diagnosis", "gyro", "noise", "mag",
    }  # fmt: skip
    imports: dict[str, set[str]] = {}
    for p in cal.rglob("*.py"):
        mod = "accellog." + ".".join(p.relative_to(PKG).with_suffix("").parts)
        imports[mod] = {
            n.module
            for n in ast.walk(ast.parse(p.read_text()))
            if isinstance(n, ast.ImportFrom) and (n.module or "").startswith("accellog.calibrate.")
        }
    circles = sorted(
        {tuple(sorted((a, b))) for a, deps in imports.items() for b in deps if a in imports.get(b, ())}
    )
    assert circles == []


MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80
"""Function length = end_lineno - lineno of its `def` (docstring and body, decorators not counted)."""

ALLOWED_MODULES = {
    "acquire/driver.py": "one register-level device (probe, configure, FIFO, magnetometer bypass, error "
    "recovery) kept whole so the register protocol reads in one place beside registers.py",
    "acquire/emulator/chip.py": "the emulated chip: the same register protocol as driver.py, kept whole",
    "calibrate/diagnosis/diagnose.py": "one diagnosis for both residuals (labelled per axis, hand-held on "
    "the gravity norm): one nested test, one ranking, one verdict rule and choice, side by side",
    "flows/workbench.py": "the one discovery loop (labelled or hand-held: a residual strategy), the effects "
    "it keeps, its ladder and the workbench run, read in one place; the search's record: workbench_trail",
    "store/reader.py": "an accellog MCAP file into a Session in one module: the fast or generic collect, the "
    "/imu columns converted group by group while the walk goes on, the other topics, the summary facts",
    "calibrate/calfile/calibration.py": "the calibration file in one module: its typed sections read and "
    "written byte for byte, the provenance, the correction it applies and its notebook views",
    "flows/stages.py": "the batch stages in one module (fit, segment, evaluate, drift, integrate), each "
    "opening one Source and making its passes, its typed result beside it: one place per stage",
}
ALLOWED_FUNCTIONS = {}
"""Exceptions to the size limits, each with its reason (docs/architecture.md repeats them)."""


def _sizes() -> tuple[dict[str, int], dict[str, int]]:
    """(lines per module, lines per function 'module.py:name' incl. methods and nested functions)."""
    modules, functions = {}, {}
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(PKG).as_posix()
        src = p.read_text()
        modules[rel] = len(src.splitlines())
        for n in ast.walk(ast.parse(src)):
            if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef):
                key = f"{rel}:{n.name}"
                functions[key] = max(functions.get(key, 0), n.end_lineno - n.lineno)
    return modules, functions


def test_modules_and_functions_stay_small():
    """No module over 500 lines, no function over 80, unless ALLOWED_* names it with a reason."""
    modules, functions = _sizes()
    big_m = {m: n for m, n in modules.items() if n > MAX_MODULE_LINES and m not in ALLOWED_MODULES}
    big_f = {f: n for f, n in functions.items() if n > MAX_FUNCTION_LINES and f not in ALLOWED_FUNCTIONS}
    assert big_m == {}, f"modules over {MAX_MODULE_LINES} lines: split them along their seams"
    assert big_f == {}, f"functions over {MAX_FUNCTION_LINES} lines: break them into named steps"


def test_size_allow_list_names_only_real_exceptions():
    """Every allow-list entry exists and is still over its limit (remove it once it is not)."""
    modules, functions = _sizes()
    stale = [m for m in ALLOWED_MODULES if modules.get(m, 0) <= MAX_MODULE_LINES]
    stale += [f for f in ALLOWED_FUNCTIONS if functions.get(f, 0) <= MAX_FUNCTION_LINES]
    assert stale == []


def _run_cli_in_fresh_python(args: list[str], env: dict[str, str], after: str) -> str:
    """stdout of `after` (Python printing JSON) run after accellog.cli.main(args) in a new interpreter."""
    code = (
        "import contextlib, io, json, os, sys\n"
        "from accellog.cli import main\n"
        f"with contextlib.redirect_stdout(io.StringIO()): rc = main({args!r})\n"
        "assert rc == 0\n" + after
    )
    return subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout


def _env_without_blas_vars() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in BLAS_VARS}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return env


BLAS_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def test_help_loads_neither_numpy_nor_threadpoolctl():
    out = _run_cli_in_fresh_python(
        ["--help"],
        _env_without_blas_vars(),
        "print(json.dumps(sorted({'numpy', 'threadpoolctl'} & set(sys.modules))))",
    )
    assert json.loads(out) == []


def test_commands_run_blas_on_one_thread_unless_the_user_says_otherwise():
    """numpy loads inside the command, after main() set the BLAS variables: threadpoolctl (asked after
    the command) sees every BLAS library on one thread; a variable the user set is left alone."""
    ask = (
        "from threadpoolctl import threadpool_info\n"
        "blas = [i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas']\n"
        f"print(json.dumps({{'blas': blas, 'env': {{k: os.environ.get(k) for k in {BLAS_VARS!r}}}}}))"
    )
    env = _env_without_blas_vars()
    got = json.loads(_run_cli_in_fresh_python(["effects"], env, ask))
    assert got["blas"] and set(got["blas"]) == {1}
    assert got["env"] == dict.fromkeys(BLAS_VARS, "1")
    env["OPENBLAS_NUM_THREADS"] = "2"
    got = json.loads(_run_cli_in_fresh_python(["effects"], env, ask))
    assert got["env"] == {"OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
