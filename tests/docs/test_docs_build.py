"""The manual builds with warnings as errors: a broken link, a page outside every toctree, a
docstring the API pages cannot read or a bad cross-reference fails here, naming the page."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_manual_builds_without_warnings(tmp_path):
    out = tmp_path / "html"
    res = subprocess.run(
        [str(ROOT / "scripts" / "docs"), str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, f"scripts/docs failed:\n{res.stdout[-4000:]}\n{res.stderr[-4000:]}"
    for page in ("index", "install", "faults", "reference/config", "api/model"):
        assert (out / f"{page}.html").is_file(), f"no {page}.html in the build"
