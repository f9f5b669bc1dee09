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


def _readme_install() -> list[str]:
    """The README's install command (its first line), as arguments after `pip`."""
    first = (ROOT / "README.md").read_text(encoding="utf-8").split("```bash\n", 1)[1].splitlines()[0]
    command = first.split("#", 1)[0].split()
    assert command[:3] == ["pip", "install", "-e"], first
    return command[1:]


@pytest.mark.slow  # a virtual environment and an editable install: ~20 s
def test_readme_install_lets_mypy_see_the_types(tmp_path: Path) -> None:
    """After the README's install line (an editable install) a user's mypy finds accellog without
    any path given: setuptools' default editable finder is an import hook mypy cannot follow."""
    import shutil
    import venv

    src = tmp_path / "src"  # a copy of the checkout: the install writes build files beside it
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".git", "tests", "*.egg-info", "__pycache__"))
    env_dir = tmp_path / "env"
    venv.create(env_dir, system_site_packages=True, with_pip=True)  # mypy and the dependencies: the suite's
    py = env_dir / "bin" / "python"
    args = [a if a != "." else str(src) for a in _readme_install()]
    subprocess.run([str(py), "-m", "pip", "-q", *args, "--no-deps"], check=True, cwd=tmp_path, timeout=600)
    script = tmp_path / "user" / "notebook.py"
    script.parent.mkdir()
    script.write_text(_readme_snippet() + "reveal_type(fit)\n", encoding="utf-8")
    run = subprocess.run(
        [str(py), "-m", "mypy", "--no-error-summary", "--cache-dir", str(tmp_path / "cache"), str(script)],
        cwd=script.parent,
        env={k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MYPYPATH")},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert ": error:" not in run.stdout, run.stdout
    assert 'Revealed type is "accellog.calibrate.model.fit.FitResult"' in run.stdout, run.stdout


@pytest.mark.slow  # mypy over the whole package: ~35 s
def test_package_is_clean() -> None:
    """`mypy accellog` with the project's configuration: no error."""
    out = _mypy("accellog", cwd=ROOT)
    errors = [ln for ln in out if ": error:" in ln]
    assert not errors, f"{len(errors)} mypy errors:\n" + "\n".join(errors)
