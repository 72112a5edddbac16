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
    1.5x the no-payload figure; hidden from the config it is larger (the payload acts). Through
    the circle's cable reversals the compensated max error of the reference run stays within 3x
    its mean (2.94x at this rate, about twice the paper's; the paper's slow circle with
    identified parameters, 2.6x, is the effects page's command)."""
    out = subprocess.run(
        [sys.executable, "scripts/effects_experiments.py", "--phi-rate", "0.6", "--out",
         str(tmp_path / "effects-quick")],
        cwd=ROOT, capture_output=True, text=True, timeout=580, check=True,
    ).stdout  # fmt: skip
    rows = re.findall(r"^(?:no payload|payload).*?\s([\d.]+)\s+([\d.]+)\s+[\d.]+$", out, re.M)
    assert len(rows) == 3, out
    (ref, ref_max), (with_cfg, _), (hidden, _) = [(float(a), float(b)) for a, b in rows]
    assert ref_max <= 3.0 * ref, out
    assert with_cfg <= 1.5 * ref
    assert hidden > with_cfg + 0.05  # 5 g on the 90 mm robot: ~0.14 mm of mean error
    assert "holds: True" in out
