"""The validated YAML rig config: the single source of truth for every parameter.

:func:`load_rig_config`, :func:`load_yaml_model` and :class:`RigConfig` are imported on first
use (PEP 562): the loader imports every registered design and its model (and with them
``scipy.optimize``), which a process that needs only a config section's schema
(``cdcr_ctl.config.control``: the daemon's stop-line process) does not.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cdcr_ctl.config.loader import load_rig_config, load_yaml_model
    from cdcr_ctl.config.schema import RigConfig

__all__ = ["RigConfig", "load_rig_config", "load_yaml_model"]


def __getattr__(name: str) -> Any:
    if name in ("load_rig_config", "load_yaml_model"):
        from cdcr_ctl.config import loader

        return getattr(loader, name)
    if name == "RigConfig":
        from cdcr_ctl.config.schema import RigConfig

        return RigConfig
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
