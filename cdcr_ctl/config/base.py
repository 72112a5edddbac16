"""Shared pydantic base for every config section.

Unknown keys are rejected (a typo must not silently fall back to a default) and numbers are strict:
``length_mm: "90 mm"`` or ``"90"`` is an error, not a conversion. Units live in key names.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

#: Sensor and link timeouts (s): a reading older than 10 s leaves the arm moving blind for
#: thousands of cycles; no sensor or link this controller reads is that slow.
TIMEOUT_MAX_S = 10.0

#: A timeout or staleness bound in seconds: positive, finite, at most :data:`TIMEOUT_MAX_S`.
Timeout = Annotated[float, Field(gt=0, le=TIMEOUT_MAX_S, allow_inf_nan=False)]


class Section(BaseModel):
    """Base class of all config sections: frozen, strict, no unknown keys."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)
