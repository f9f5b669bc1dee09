"""Every fenced ```bash block of README.md runs as printed, then the ```python blocks (in one
interpreter, in order, as a notebook runs them).
README.md is read when the tests are collected, so the test follows whatever the README says.

How the blocks are run (README commands must be written so that they run under these rules):
- In README order, each block as one bash script (``set -eo pipefail``: the first failing command
  fails the block), all in one scratch folder laid out like a checkout: SCRATCH/repo is the working
  directory and holds links to the repository's examples/, pipelines/ and docs/; SCRATCH/shared/data mirrors
  the checkout's ../shared/data when it exists (its folders made anew, its files linked: a command that
  writes there writes into SCRATCH, never into the shared data). Commands therefore name their inputs examples/...,
  pipelines/... (or files an earlier command wrote) and write their outputs in the working directory;
  a later block may use what an earlier block wrote.
- ``accellog`` is this checkout's (``python -m accellog``), whatever is on PATH.
- Not run (the line becomes a no-op): installation and the test suite (lines starting with ``pip``
  or ``python -m pytest``), ``accellog view`` (a window or a browser) and ``accellog demo`` (minutes on
  a loaded machine); ACCELLOG_README_ALL=1 runs ``demo`` too.
- Hardware: ``accellog record --bus N ...`` runs as ``accellog record --sim --fast ...`` (the emulated
  chip on a simulated clock), at ``--rate 100`` unless the line names a rate.
- A block that names ../shared/data (the real recordings) is skipped when that folder is missing.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```", re.S | re.M)
SKIP = re.compile(r"^\s*(pip\s|python\s+-m\s+pytest|accellog\s+view\b)")
SLOW = re.compile(r"^\s*accellog\s+demo\b")


def blocks(kind: str) -> list[str]:
    """The README's fenced blocks of one language, in order."""
    return [body for lang, body in FENCE.findall(README.read_text()) if lang == kind]


def logical_lines(block: str) -> list[str]:
    """Lines with backslash continuations joined."""
    out, cur = [], ""
    for line in block.splitlines():
        if line.rstrip().endswith("\\"):
            cur += line.rstrip()[:-1] + " "
            continue
        out.append(cur + line)
        cur = ""
    return out + ([cur] if cur else [])


def runnable(line: str) -> str:
    """The line as the test runs it (module docstring): skipped, or the hardware made emulated."""
    if SKIP.match(line) or (SLOW.match(line) and not os.environ.get("ACCELLOG_README_ALL")):
        return f": skipped {shlex.quote(line.strip())}"
    if re.match(r"^\s*accellog\s+record\b", line) and "--bus" in line:
        line = re.sub(r"--bus\s+\S+", "--sim --fast", line)
        if "--rate" not in line:
            line = line.replace("--sim --fast", "--sim --fast --rate 100", 1)
    return line


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    """SCRATCH/repo with links to examples/, pipelines/, docs/; SCRATCH/shared/data mirroring ../shared/data."""
    top = tmp_path_factory.mktemp("readme")
    work = top / "repo"
    work.mkdir()
    for name in ("examples", "pipelines", "docs"):
        (work / name).symlink_to(ROOT / name)
    shared = ROOT.parent / "shared" / "data"
    if shared.is_dir():  # folders made here, files linked: what a command writes stays in SCRATCH
        for f in shared.rglob("*"):
            if f.is_file():
                dest = top / "shared" / "data" / f.relative_to(shared)
                dest.parent.mkdir(parents=True, exist_ok=True)
                dest.symlink_to(f)
    return work


def _env() -> dict:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    env["ACCELLOG_PYTHON"] = sys.executable
    return env


BASH = blocks("bash")
PYTHON = blocks("python")


def test_rules_rewrite_hardware_and_skip_installs():
    assert runnable("accellog record --bus 1 --hold 20 -o c.mcap") == (
        "accellog record --sim --fast --rate 100 --hold 20 -o c.mcap"
    )
    assert (
        runnable("accellog record --bus 1 --rate 100 -o c.mcap")
        == "accellog record --sim --fast --rate 100 -o c.mcap"
    )
    assert runnable("pip install -e . && accellog demo").startswith(": skipped")
    assert logical_lines("a \\\n  b\nc") == ["a    b", "c"]
    assert BASH, "README.md has no ```bash block"


@pytest.mark.slow
@pytest.mark.parametrize("k", range(len(BASH)), ids=[f"bash-{k + 1}" for k in range(len(BASH))])
def test_readme_bash_block_runs(k, scratch):
    block = BASH[k]
    if "../shared/data" in block and not (scratch.parent / "shared" / "data").is_dir():
        pytest.skip("needs ../shared/data (the real recordings)")
    script = "\n".join(
        [
            "set -eo pipefail",
            'accellog() { "$ACCELLOG_PYTHON" -m accellog "$@"; }',
            "export -f accellog",
            *(runnable(line) for line in logical_lines(block)),
        ]
    )
    got = subprocess.run(["bash", "-c", script], cwd=scratch, env=_env(), capture_output=True, text=True,
                         timeout=600)  # fmt: skip
    assert got.returncode == 0, f"README block {k + 1} failed:\n{script}\n--- stderr:\n{got.stderr[-3000:]}"


RUN_PYTHON = """
import sys
ns = {"__name__": "__readme__"}
for k, code in enumerate(BLOCKS, 1):
    try:
        exec(compile(code, f"README python block {k}", "exec"), ns)
    except Exception as exc:
        print(f"README python block {k} failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        sys.exit(1)
"""


@pytest.mark.slow
def test_readme_python_blocks_run(scratch):
    """The ```python blocks in order in one interpreter (as a notebook would), after the bash blocks
    (their outputs are in the scratch folder)."""
    code = f"BLOCKS = {PYTHON!r}\n" + RUN_PYTHON
    got = subprocess.run([sys.executable, "-c", code], cwd=scratch, env=_env(), capture_output=True, text=True,
                         timeout=600)  # fmt: skip
    assert got.returncode == 0, got.stderr[-3000:]
