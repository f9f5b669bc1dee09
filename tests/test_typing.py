"""Static types: a user's script with the README's notebook snippet sees accellog's real types, and
``mypy accellog`` (configured in pyproject.toml) reports no error."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Files restructured by the one-source redesign (issue 41) whose errors are not fixed yet; the list
# shrinks to nothing and goes with the xfail marker below.
PENDING_MYPY = [
    "accellog/calibrate/diagnosis/diagnose.py",
    "accellog/calibrate/diagnosis/transfer.py",
    "accellog/flows/stages.py",
    "accellog/flows/workbench.py",
]

pytest.importorskip("mypy")


def _mypy(*args: str, cwd: Path, env: dict[str, str] | None = None) -> list[str]:
    """mypy's error lines (file:line: error: ...) for the arguments, run in cwd."""
    run = subprocess.run(
        [sys.executable, "-m", "mypy", "--no-error-summary", "--show-error-codes", *args],
        cwd=cwd,
        env={**os.environ, **(env or {})},
        capture_output=True,
        text=True,
        timeout=600,
    )
    if run.returncode not in (0, 1):  # 2: mypy itself failed (bad config, crash)
        raise AssertionError(f"mypy failed:\n{run.stdout}\n{run.stderr}")
    return run.stdout.splitlines()


def _readme_snippet() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    m = re.search(r"From a notebook:\s*```python\n(.*?)```", text, re.S)
    assert m is not None, "the README's notebook snippet (```python after 'From a notebook:') is gone"
    return m.group(1)


def test_readme_snippet_sees_real_types(tmp_path: Path) -> None:
    """The snippet type-checks, and its names have accellog's types, not Any (py.typed is shipped)."""
    assert (ROOT / "accellog" / "py.typed").is_file()
    script = tmp_path / "notebook.py"
    script.write_text(
        _readme_snippet() + "reveal_type(s)\nreveal_type(obs)\nreveal_type(fit)\n", encoding="utf-8"
    )
    # accellog found on the path as a user's install puts it there; as for any installed package, only
    # the user's own file is reported (--follow-imports=silent)
    out = _mypy(
        "--follow-imports=silent",
        "--python-version=3.11",
        "--cache-dir",
        str(tmp_path / "cache"),
        str(script),
        cwd=tmp_path,
        env={"MYPYPATH": str(ROOT)},
    )
    errors = [ln for ln in out if ": error:" in ln]
    assert not errors, "\n".join(errors)
    revealed = [ln.split("Revealed type is ", 1)[1] for ln in out if "Revealed type is" in ln]
    assert revealed == [
        '"accellog.core.session.Session"',
        '"accellog.core.session.ObsTable"',
        '"accellog.calibrate.model.fit.FitResult"',
    ], out


@pytest.mark.slow  # mypy over the whole package: ~35 s
@pytest.mark.xfail(
    strict=True,
    reason="25 errors outside PENDING_MYPY remain (gyro/stream.py's pass state, the residual functions' "
    "attributes, record_starts' buffer types, online's carried integrals, callers of stages.py's signatures); "
    "this marker goes once they are fixed",
)
def test_package_is_clean() -> None:
    """`mypy accellog` with the project's configuration: no error outside PENDING_MYPY."""
    out = _mypy("accellog", cwd=ROOT)
    errors = [ln for ln in out if ": error:" in ln and ln.split(":", 1)[0] not in PENDING_MYPY]
    assert not errors, f"{len(errors)} mypy errors:\n" + "\n".join(errors)
