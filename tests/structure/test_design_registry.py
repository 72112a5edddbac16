"""The design registry (cdcr_ctl.config.registry): no layer branches on a design's name, and a
new design is one package plus one registry line. A fourth, toy design (one rigid segment bent by
two antagonistic cables, no section of its own) is registered here and served through the
registry alone: its rig config loads, the loop's model and the simulated truth are its own."""

from __future__ import annotations

import ast
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.config.registry import DESIGNS, Design, design_of, register
from cdcr_ctl.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]
PKG = ROOT / "cdcr_ctl"
#: Branches on a design's name in the two packages being rewritten elsewhere: each to be
#: replaced by a registry look-up (then removed from here).
PENDING: set[str] = set()


def _design_branches(path: Path) -> list[int]:
    """Lines comparing a ``design`` (a name or an attribute) with a string or a tuple of them."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.Compare):
            continue
        sides = [node.left, *node.comparators]
        names = {getattr(s, "id", None) or getattr(s, "attr", None) for s in sides}
        consts = [
            s
            for s in sides
            if isinstance(s, ast.Constant | ast.Tuple | ast.List | ast.Set)
            and any(isinstance(c, ast.Constant) and isinstance(c.value, str) for c in ast.walk(s))
        ]
        if "design" in names and consts:
            out.append(node.lineno)
    return out


def test_no_layer_branches_on_a_design_name():
    found = {
        str(p.relative_to(ROOT)): lines
        for p in sorted(PKG.rglob("*.py"))
        if (lines := _design_branches(p))
    }
    assert set(found) - PENDING == set(), found


class ToyModel:
    """One segment, bend theta in the plane phi, two cables at +-r: q = -+ r theta cos phi."""

    n_segments, n_cables = 1, 2

    def __init__(self, r_mm: float, length_mm: float) -> None:
        self.r, self.L = r_mm, length_mm

    def new_state(self) -> None:
        return None

    def q_nominal(self, psi: np.ndarray) -> np.ndarray:
        d = self.r * psi[0, 0] * math.cos(psi[0, 1])
        return np.array([d, -d])

    def q_command(self, psi, q_nominal, state, mode, measured_N) -> np.ndarray:
        return np.asarray(q_nominal, dtype=float)

    def tip(self, psi: np.ndarray) -> np.ndarray:
        t, p = psi[0]
        if t == 0.0:
            return np.array([0.0, 0.0, self.L])
        rho = self.L / t
        return np.array([rho * (1 - math.cos(t)) * math.cos(p), 0.0, rho * math.sin(t)])


class ToyTruth:
    def __init__(self, loaded) -> None:
        self.design = loaded.rig.design


def _toy_build(cfg, source, effects, band):
    return ToyModel(cfg.robot.cables[0].routing_radius_mm, cfg.robot.segments[0].length_mm)


@pytest.fixture
def toy():
    design = register(
        Design(
            "toy_rigid",
            "a test design",
            None,
            lambda cfg: [],
            _toy_build,
            ToyTruth,
            lambda rig_cfg, quick: {},
            "sim/qi2023-truth-clean.yaml",
        )
    )
    yield design
    del DESIGNS["toy_rigid"]


def test_a_fourth_design_is_served_through_the_registry_alone(toy, tmp_path):
    from cdcr_ctl.sim.design_truth import make_truth

    doc = yaml.safe_load((ROOT / "config" / "qi2023.yaml").read_text(encoding="utf-8"))
    doc["design"] = "toy_rigid"
    rig = tmp_path / "toy.yaml"
    rig.write_text(yaml.safe_dump(doc), encoding="utf-8")
    cfg = load_rig_config(rig)
    assert design_of(cfg.design) is toy
    model = build_model(cfg)
    assert isinstance(model, ToyModel)
    r = cfg.robot.cables[0].routing_radius_mm
    # a bend of 0.3 rad in the cables' plane: the first cable pulled in r * 0.3 mm
    q = model.q_nominal(np.array([[0.3, 0.0]]))
    assert q.tolist() == pytest.approx([r * 0.3, -r * 0.3], rel=1e-15)
    truth = make_truth(SimpleNamespace(rig=cfg))
    assert isinstance(truth, ToyTruth) and truth.design == "toy_rigid"


def test_an_unregistered_design_is_refused_naming_the_registered_ones(tmp_path):
    doc = yaml.safe_load((ROOT / "config" / "qi2023.yaml").read_text(encoding="utf-8"))
    doc["design"] = "no_such_design"
    rig = tmp_path / "bad.yaml"
    rig.write_text(yaml.safe_dump(doc), encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        load_rig_config(rig)
    text = str(err.value)
    assert "design" in text and "no_such_design" in text
    assert all(name in text for name in ("cc_disk", "ujoint", "vertebra"))
