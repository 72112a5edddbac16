"""Shared pydantic base for every config section.

Unknown keys are rejected (a typo must not silently fall back to a default) and numbers are strict:
``length_mm: "90 mm"`` or ``"90"`` is an error, not a conversion. Units live in key names.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Section(BaseModel):
    """Base class of all config sections: frozen, strict, no unknown keys."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)
