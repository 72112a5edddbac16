"""The design registry: one table from a design's name to everything that serves it.

A robot design is one package under :mod:`cdcr_ctl.model` plus one :class:`Design` line in
:data:`DESIGNS` (or a :func:`register` call). The line names

- its config: the rig config's section of its own (``section``: the ``RigConfig`` key, None for a
  design without one), its cross-section ``check`` (problems in the shape of
  ``loader.cross_check``), and the ``build`` of the loop's model (:class:`RobotModelPort`) from a
  validated ``RigConfig``;
- for the layers above the config, by ``"module:attribute"`` (each resolved by the layer that uses
  it, :func:`resolve`, never imported here): its simulated ``truth`` (a class taking a
  ``LoadedSim``, :mod:`cdcr_ctl.sim.design_truth`), its ``demo`` (the demo's timed trajectories,
  :mod:`cdcr_ctl.cli.demo`) and the simulator config the demo runs by default (``sim_config``,
  relative to the checkout's ``config/``); whether :mod:`cdcr_ctl.identify` fits its parameters
  (``identify``), and how the live view draws it (``backbone``: ``"cc"`` the constant-curvature
  arcs, ``"tip_line"`` the line base - model tip).

``RigConfig.design`` accepts exactly the registered names; every layer looks its design up here
instead of branching on the name. Below the schema: the modules it imports do not import the
schema (they take the ``RigConfig`` as ``Any``).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from cdcr_ctl.config import designs_cc_disk, designs_ujoint, designs_vertebra
from cdcr_ctl.config.designs_common import no_cc_disk_options
from cdcr_ctl.config.keys import KeyPath
from cdcr_ctl.model.port import RobotModelPort

#: A cross-section check: problems (key path, message, value) of a ``RigConfig``.
Check = Callable[[Any], list[tuple[KeyPath, str, Any]]]
#: A model builder: (rig config, file named in errors, cc_disk's effects, its reversal band).
Build = Callable[[Any, str, Any, Any], RobotModelPort]


@dataclass(frozen=True)
class Design:
    """Everything that serves one design (see the module docstring)."""

    name: str
    summary: str
    section: str | None
    check: Check
    build: Build
    truth: str | Callable[..., Any]
    demo: str | Callable[..., Any]
    sim_config: str
    identify: bool = False
    backbone: str = "tip_line"


def _no_checks(cfg: Any) -> list[tuple[KeyPath, str, Any]]:
    return []


def _build_cc_disk(cfg: Any, source: str, effects: Any, band: Any) -> RobotModelPort:
    return designs_cc_disk.build_cc_disk_model(cfg, effects, band, source)


def _build_ujoint(cfg: Any, source: str, effects: Any, band: Any) -> RobotModelPort:
    from cdcr_ctl.model.ujoint import UJointModel

    no_cc_disk_options(cfg, source, effects, band)
    return UJointModel(
        designs_ujoint.ujoint_arm(cfg, source),
        cable_velocity_mm_s=cfg.limits.cable_velocity_mm_s,
        period_s=1.0 / cfg.control.rate_hz,
    )


def _build_vertebra(cfg: Any, source: str, effects: Any, band: Any) -> RobotModelPort:
    from cdcr_ctl.model.vertebra import VertebraModel

    no_cc_disk_options(cfg, source, effects, band)
    return VertebraModel(
        designs_vertebra.vertebra_arm(cfg, source), designs_vertebra.attitude_loop_params(cfg)
    )


#: The registered designs, by name.
DESIGNS: dict[str, Design] = {
    d.name: d
    for d in (
        Design(
            "cc_disk",
            "constant-curvature disks (Qi et al. 2023)",
            None,
            _no_checks,
            _build_cc_disk,
            "cdcr_ctl.sim.truth:TruthModel",
            "cdcr_ctl.cli.demo_experiments:cc_disk",
            "sim/qi2023-truth-clean.yaml",
            identify=True,
            backbone="cc",
        ),
        Design(
            "ujoint",
            "universal-joint segments (Yang et al. 2022)",
            "ujoint",
            designs_ujoint.check_ujoint,
            _build_ujoint,
            "cdcr_ctl.sim.truth_ujoint:UJointTruth",
            "cdcr_ctl.cli.demo_experiments:ujoint",
            "sim/yang2022-truth.yaml",
        ),
        Design(
            "vertebra",
            "ball-jointed vertebrae on an elastic rod (fuel-tank arm)",
            "vertebra",
            designs_vertebra.check_vertebra,
            _build_vertebra,
            "cdcr_ctl.sim.truth_vertebra:VertebraTruth",
            "cdcr_ctl.cli.demo_experiments:vertebra",
            "sim/vertebra-truth.yaml",
        ),
    )
}


def register(design: Design) -> Design:
    """Add ``design`` to :data:`DESIGNS` (ValueError for a name already taken)."""
    if design.name in DESIGNS:
        raise ValueError(f"design {design.name!r} is registered already")
    DESIGNS[design.name] = design
    return design


def design_of(name: str) -> Design:
    """The registered design ``name`` (ValueError naming the registered ones otherwise)."""
    found = DESIGNS.get(name)
    if found is None:
        raise ValueError(f"unknown design {name!r}; registered: {', '.join(sorted(DESIGNS))}")
    return found


def check_design_section(design: str, key: str, section: object) -> None:
    """Section ``key`` is present exactly when it is ``design``'s own (ValueError otherwise);
    called by ``RigConfig``'s validator of every design section."""
    own = design_of(design).section == key
    if own and section is None:
        raise ValueError(f"design {design} needs a '{key}:' section")
    if not own and section is not None:
        owners = [d.name for d in DESIGNS.values() if d.section == key]
        raise ValueError(f"a '{key}:' section is only for design {' or '.join(owners)}")


def resolve(ref: str | Callable[..., Any]) -> Any:
    """The object a registry entry names as ``"module:attribute"`` (a callable as it is)."""
    if not isinstance(ref, str):
        return ref
    module, _, attr = ref.partition(":")
    return getattr(importlib.import_module(module), attr)
