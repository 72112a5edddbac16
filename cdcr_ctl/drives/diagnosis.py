"""What a faulted drive's own records say: the error code 0x603F and the error history 0x1003,
read by SDO after a fault and put into words (pure; the reading is the group's).

0x1003:00 is the number of entries (maxon's files: up to 5), 0x1003:01 the newest. Each entry is
a UNSIGNED32: the error code in bits 0-15 (the EMCY code), manufacturer-specific information in
bits 16-31. The EPOS2 has no 0x603F (its newest 0x1003 entry serves).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from cdcr_ctl.drives.emcy import Family, emcy_text

#: Error code 0x603F and error history 0x1003 (CiA 402 / CiA 301).
ERROR_CODE = 0x603F
ERROR_HISTORY = 0x1003
#: SDO timeout of the diagnosis reads (s): a drive that does not answer is named as such.
DIAGNOSIS_SDO_TIMEOUT_S = 0.5


@dataclass(frozen=True)
class Diagnosis:
    """0x603F (None: not read, the drive lacks it or did not answer) and the 0x1003 entries,
    newest first; ``failure`` says why reading stopped ('' when it did not)."""

    node: int
    error_code: int | None
    history: tuple[int, ...]
    family: Family = "epos4"
    failure: str = ""

    @property
    def text(self) -> str:
        parts = []
        if self.error_code is not None:
            parts.append(
                f"0x603F 0x{self.error_code:04X} {emcy_text(self.error_code, self.family)}"
            )
        if self.history:
            parts.append("0x1003 " + ", ".join(history_text(self.history, self.family)))
        elif not self.failure:
            parts.append("0x1003 empty")
        if self.failure:
            parts.append(self.failure)
        return "; ".join(parts)


def history_text(entries: Sequence[int], family: Family = "epos4") -> list[str]:
    """0x1003 entries as text: ``0xCODE text`` (+ ``(info 0xNNNN)`` when bits 16-31 are set)."""
    out = []
    for e in entries:
        code, info = e & 0xFFFF, (e >> 16) & 0xFFFF
        text = f"0x{code:04X} {emcy_text(code, family)}"
        out.append(f"{text} (info 0x{info:04X})" if info else text)
    return out
