"""Modules stay small: one job each, 500 lines at most (docs/architecture.md "Layers").

A module that reaches the limit has grown a second job: split it by job rather than squeeze it."""

from __future__ import annotations

from pathlib import Path

PKG = Path(__file__).resolve().parents[2] / "cdcr_ctl"
#: Lines a module of the package may have.
MAX_MODULE_LINES = 500


def test_no_module_is_over_the_limit():
    sizes = {
        str(p.relative_to(PKG.parent)): len(p.read_text(encoding="utf-8").splitlines())
        for p in sorted(PKG.rglob("*.py"))
    }
    assert len(sizes) > 100  # the walk found the package
    over = {path: n for path, n in sizes.items() if n > MAX_MODULE_LINES}
    assert not over, f"modules over {MAX_MODULE_LINES} lines: {over}"
