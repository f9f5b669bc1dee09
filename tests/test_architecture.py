"""The package's shape: layers import one way only; modules stay small enough to read."""

from __future__ import annotations

import ast
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
