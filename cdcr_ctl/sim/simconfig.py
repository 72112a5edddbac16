"""The simulated rig's own YAML: which rig it plays, and how its "truth" differs from the
controller's belief.

The controller and the simulator read different files. The simulator's file names the rig config
the controller uses (``rig``) for geometry, drives and connection points, and then states the truth:
``truth.robot`` is merged over the rig's ``robot`` section item by item (cables and segments by
``name``), so the world's friction, stiffness and pretension can differ from the nominal values the
controller starts with. Effects the controller's config has no key for (backlash, actuator scale
error, tracker frame offset, sensor noise) live only here.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field

from cdcr_ctl.config.base import Section
from cdcr_ctl.config.loader import load_rig_config, merge_tree, read_yaml, validate_mapping
from cdcr_ctl.config.robot import NonNegativeFloat, PositiveFloat, RobotConfig
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.config.tracking import RigidTransformConfig
from cdcr_ctl.errors import ConfigError

Probability = Annotated[float, Field(ge=0, le=1)]


class TruthEffects(Section):
    """Physical effects of the simulated world beyond the robot section.

    ``backlash_mm``: when > 0, this lost motion on every cable (else each truth cable's own
    ``backlash_mm``). ``friction_law``: ``capstan`` (the controller's law, Qi et al. 2023 eq.
    16-24), ``wrap_power`` (friction density growing with the accumulated wrap, exponent
    ``friction_exponent``) or ``stribeck`` (a speed-dependent coefficient with a stick band:
    ``friction_static_ratio`` r_s, ``friction_stribeck_mm_s`` v_s, ``friction_viscous_s_per_mm``
    c_v, the speed followed with a lag of ``friction_memory_s``); :mod:`cdcr_ctl.sim.friction_law`
    states the laws.
    """

    geometry: Literal["chord", "cc"] = "chord"
    backlash_mm: NonNegativeFloat = 0.0
    counts_per_mm_scale: Annotated[list[PositiveFloat], Field(min_length=1)] | None = None
    gravity: bool = True
    disk_friction: bool = True
    pulley_friction: bool = True
    elongation: bool = True
    coupling: bool = True
    tracker_offset: RigidTransformConfig = Field(default_factory=RigidTransformConfig)
    friction_law: Literal["capstan", "wrap_power", "stribeck"] = "capstan"
    friction_exponent: Annotated[float, Field(gt=0, le=4)] = 1.5
    friction_static_ratio: Annotated[float, Field(ge=1, le=5)] = 1.8
    friction_stribeck_mm_s: PositiveFloat = 0.5
    friction_viscous_s_per_mm: Annotated[float, Field(ge=0, le=10)] = 0.1
    friction_memory_s: NonNegativeFloat = 0.05


class NoiseConfig(Section):
    tracker_mm: NonNegativeFloat = 0.0
    load_cell_N: NonNegativeFloat = 0.0
    load_cell_drift_N_per_s: NonNegativeFloat = 0.0
    load_cell_dropout: Probability = 0.0


class TrackerSimConfig(Section):
    rate_hz: PositiveFloat = 120.0
    latency_s: NonNegativeFloat = 0.0
    dropout: Probability = 0.0


class AttitudeSimConfig(Section):
    """Simulated attitude sensors (vertebra design): output rate, Gaussian angle noise (deg),
    heading error (deg; the decode does not use yaw), latency (s)."""

    rate_hz: PositiveFloat = 100.0
    noise_deg: NonNegativeFloat = 0.0
    yaw_offset_deg: float = 0.0
    latency_s: NonNegativeFloat = 0.0


class JoystickSimConfig(Section):
    """The simulated network joystick of a rig whose ``sensors.joystick.device`` is
    ``tcp://127.0.0.1:PORT``: what each connecting client gets.

    ``script``: ``paper`` (the fuel-tank paper's Fig. 12 session,
    :func:`cdcr_ctl.model.vertebra.follow.paper_session`, with the rig's advance button) or a
    YAML stick script (:func:`cdcr_ctl.sim.joystick.load_stick_script`; a path relative to this
    file). ``scale``: shortens the paper session's bend moves (0, 1]. ``disconnect_after_s``:
    drop the connection this long after the client connected (s; a sender unplugged
    mid-session); None: keep it until the client leaves.
    """

    script: Annotated[str, Field(min_length=1)] = "paper"
    scale: Annotated[float, Field(gt=0, le=1)] = 1.0
    disconnect_after_s: PositiveFloat | None = None


class SimConfig(Section):
    """Top level of a simulator YAML file.

    ``truth_design``: merged over the rig's design section (``ujoint:``/``vertebra:``) for the
    world (:func:`cdcr_ctl.sim.design_truth.truth_rig_config`); ``attitude``: the simulated
    attitude sensors of a rig with ``sensors.attitude``; ``joystick``: the stick session the
    simulated network joystick plays (a rig whose joystick device is ``tcp://``).
    """

    rig: Annotated[str, Field(min_length=1)]
    truth_robot: dict[str, Any] = Field(default_factory=dict)
    truth_design: dict[str, Any] = Field(default_factory=dict)
    attitude: AttitudeSimConfig = Field(default_factory=AttitudeSimConfig)
    effects: TruthEffects = Field(default_factory=TruthEffects)
    noise: NoiseConfig = Field(default_factory=NoiseConfig)
    tracker: TrackerSimConfig = Field(default_factory=TrackerSimConfig)
    joystick: JoystickSimConfig = Field(default_factory=JoystickSimConfig)
    physics_rate_hz: PositiveFloat = 500.0
    seed: int = 1


class LoadedSim:
    """A validated simulator config: the rig as the controller sees it and the truth robot."""

    def __init__(self, path: Path, sim: SimConfig, rig: RigConfig, truth: RobotConfig) -> None:
        self.path = path
        self.sim = sim
        self.rig = rig
        self.rig_path = (path.parent / sim.rig).resolve()
        self.truth = truth


def load_sim_config(path: str | Path) -> LoadedSim:
    """Load a simulator YAML, the rig config it names, and merge the truth robot over it."""
    path = Path(path)
    data = read_yaml(path)
    sim = validate_mapping(data, SimConfig, str(path))
    rig_path = (path.parent / sim.rig).resolve()
    rig = load_rig_config(rig_path)
    base = rig.robot.model_dump(exclude_none=True)
    merged = merge_tree(base, sim.truth_robot, (), {}, str(path))
    try:
        truth = validate_mapping(merged, RobotConfig, str(path))
    except ConfigError as exc:
        raise ConfigError(str(path), f"truth_robot.{exc.key}", exc.detail, exc.value) from exc
    scale = sim.effects.counts_per_mm_scale
    if scale is not None and len(scale) != len(rig.drives):
        raise ConfigError(
            str(path), "effects.counts_per_mm_scale", f"needs {len(rig.drives)} values", scale
        )
    return LoadedSim(path, sim, rig, truth)


def sim_owned_keys(
    rig: RigConfig, can_interface: str = "slcan", link_paths: bool = True
) -> list[str]:
    """What a simulator of ``rig`` stands in for, as :mod:`cdcr_ctl.ownership` keys: its pty
    links (the CAN adapter's, the load cells', the attitude sensors'; with ``link_paths``) and
    its loopback ports (tracker, network joystick). A second simulator of the same rig refuses
    on the first of them, before it replaces a link or binds a port."""
    keys: list[str] = []
    sensors = rig.sensors
    if link_paths:
        links = [rig.can.channel] if can_interface == "slcan" else []
        if sensors.load_cells is not None:
            links.append(sensors.load_cells.serial.port)
        if sensors.attitude is not None:
            links += [s.port for s in sensors.attitude.sensors]
        # A link on a loopback TCP port (socket://127.0.0.1:PORT) is that port.
        keys += [
            "sim-port:" + link.removeprefix("socket://")
            if link.startswith("socket://")
            else f"sim:{os.path.abspath(link)}"
            for link in links
        ]
    if sensors.tracker is not None:
        tr = sensors.tracker
        keys.append(f"sim-port:{tr.host}:{tr.command_port if tr.kind == 'natnet' else tr.port}")
    js = sensors.joystick
    if js is not None and js.tcp_address is not None:
        keys.append("sim-port:{}:{}".format(*js.tcp_address))
    return keys
