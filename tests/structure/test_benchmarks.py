"""Every script in ``benchmarks/`` produces a figure the manual shows: each is named, as
``benchmarks/<script>.py``, on a page under ``docs/`` (most in docs/performance/figures.md, beside
the figure it measured). A script no page names is an investigation: git keeps it."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_benchmark_is_named_by_a_docs_page():
    scripts = sorted(p.name for p in (ROOT / "benchmarks").glob("*.py"))
    assert len(scripts) > 5  # the walk found them
    docs = "\n".join(p.read_text(encoding="utf-8") for p in (ROOT / "docs").rglob("*.md"))
    unnamed = [s for s in scripts if f"benchmarks/{s}" not in docs]
    assert unnamed == []
