"""The validated YAML rig config: the single source of truth for every parameter."""

from cdcr_ctl.config.loader import load_rig_config, load_yaml_model
from cdcr_ctl.config.schema import RigConfig

__all__ = ["RigConfig", "load_rig_config", "load_yaml_model"]
