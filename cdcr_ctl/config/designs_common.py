"""What the design sections of the rig config share (:mod:`cdcr_ctl.config.designs`): tolerances,
the refusal of cc_disk's options by the other designs' builders, the drives' counts_per_mm
check, and raising the collected problems as :class:`ConfigErrors`."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field

from cdcr_ctl.config.keys import KeyPath, format_key
from cdcr_ctl.errors import ConfigError, ConfigErrors

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]

#: Relative mismatch allowed between a drive's counts_per_mm and the design's transmission.
COUNTS_PER_MM_REL_TOL = 1e-3
#: Absolute mismatch allowed between segment length and its sub-joint geometry (mm).
LENGTH_TOL_MM = 1e-6


def no_cc_disk_options(cfg: Any, source: str, effects: Any, band: Any) -> None:
    """A model builder of a design other than cc_disk refuses cc_disk's options: ``effects``,
    the reversal band (``band``) and a tip load (:class:`ConfigError` naming ``source``)."""
    if effects is not None or band is not None:
        raise ConfigError(source, "design", "effects/reversal band are cc_disk options", cfg.design)
    tl = cfg.robot.tip_load
    if tl.payload_kg or any(tl.force_N):
        raise ConfigError(
            source,
            "robot.tip_load",
            f"the {cfg.design} model has no tip load; only cc_disk carries one",
            tl.model_dump(),
        )


def _check_counts(
    cfg: Any, expected: float, source: str, only: str | None = None, index: int | None = None
) -> list[tuple[KeyPath, str, Any]]:
    out: list[tuple[KeyPath, str, Any]] = []
    for i, drv in enumerate(cfg.drives):
        if only is not None and drv.cable != only:
            continue
        if abs(abs(drv.counts_per_mm) - expected) > COUNTS_PER_MM_REL_TOL * expected:
            out.append(
                (
                    ("drives", i, "counts_per_mm"),
                    f"does not match {source} ({expected:.6g} counts per mm)",
                    drv.counts_per_mm,
                )
            )
    return out


def _raise_problems(problems: list[tuple[KeyPath, str, Any]], source: str) -> None:

    if problems:
        raise ConfigErrors([ConfigError(source, format_key(k), m, v) for k, m, v in problems])
