"""System: scripts/effects_experiments.py, the tip-payload measurement of the docs
(docs/calibration/effects-and-loads.md), as typed there, on the lock-step simulated rig."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(600)
def test_payload_in_the_config_keeps_the_error_of_no_payload(tmp_path):
    """Hard world, quick circle: with the 5 g payload in the config the mean tip error is within
    1.5x the no-payload figure; hidden from the config it is larger (the payload acts)."""
    out = subprocess.run(
        [sys.executable, "scripts/effects_experiments.py", "--phi-rate", "0.6", "--out",
         str(tmp_path / "effects-quick")],
        cwd=ROOT, capture_output=True, text=True, timeout=580, check=True,
    ).stdout  # fmt: skip
    means = [
        float(m)
        for m in re.findall(r"^(?:no payload|payload).*?\s([\d.]+)\s+[\d.]+\s+[\d.]+$", out, re.M)
    ]
    assert len(means) == 3, out
    ref, with_cfg, hidden = means
    assert with_cfg <= 1.5 * ref
    assert hidden > with_cfg + 0.05  # 5 g on the 90 mm robot: ~0.14 mm of mean error
    assert "holds: True" in out
