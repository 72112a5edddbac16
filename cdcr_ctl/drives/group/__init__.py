"""All EPOS drives of a rig on one CAN bus: boot and SDO configuration, cyclic set-points by RPDO +
SYNC, feedback by TPDO, EMCY and heartbeat supervision, CiA 402 state changes with explicit
timeouts, homing, profile moves, halt, quick stop.

Protocol only: a drive is a node id, counts and a mode (PDO layout in :mod:`cdcr_ctl.drives.epos`).

The loop's path (never blocks on the bus, never waits for an answer):

- :meth:`DriveGroup.build_cycle` -- every frame of one cycle, built first: each drive's set-point
  RPDO, then SYNC (COB-ID 0x080). Pure: it neither sends nor changes the group.
- :meth:`DriveGroup.send_cycle` -- sends them as one burst (one write on an slcan adapter:
  :meth:`~cdcr_ctl.drives.slcan.SlcanBus.send_frames`), then checks each drive's feedback
  deadline and heartbeat deadline, every SYNC, in O(1) while nothing is overdue (the earliest
  deadline is kept; the drives are scanned only once it has passed);
  :meth:`DriveGroup.feedback` -- the latest TPDO of each drive as :class:`Feedback`.
- :meth:`DriveGroup.quick_stop_all` -- controlword 0x0002 to every drive at once; never raises.

Reception: the group's dispatcher is the bus listener's only listener (canopen's
MessageListener is replaced): every frame goes into the frame ring (and the traffic log), the
feedback TPDOs are decoded there with one ``struct`` unpack, everything else goes on to canopen
(SDO, EMCY, heartbeat). An slcan adapter hands the TPDOs over without a ``can.Message``
(:meth:`~cdcr_ctl.drives.slcan.SlcanBus.set_frame_hook`). When no SYNC went out for longer than
the feedback timeout (start-up, a paused loop), a drive's silence counts from the next SYNC.

Faults (an EMCY, a drive reporting FAULT, a heartbeat overdue or a drive restarting, TPDOs missing
for :data:`TPDO_MISSES` SYNCs from one drive or from all of them, a send or receive failure on the
bus) are latched as one :class:`GroupFault` naming node and code, answered at once with
:meth:`DriveGroup.quick_stop_all` from whichever thread saw them (and, should that thread lose the
race, by the next :meth:`~DriveGroup.send_cycle` before its SYNC), so every drive gets its quick
stop within the SYNC period the fault was seen in; then logged with the last :data:`FRAME_RING`
frames. The loop reads :meth:`DriveGroup.first_fault`.

Off the loop's path (blocking, with named timeouts): :meth:`~DriveGroup.boot`,
:meth:`~DriveGroup.configure`, :meth:`~DriveGroup.enable`, :meth:`~DriveGroup.reset_faults`,
:meth:`~DriveGroup.home`, :meth:`~DriveGroup.move_to`. They confirm every step from the TPDO
feedback; when no cycle is running the group sends the SYNCs itself, at the configured period.

Parts (:class:`DriveGroup` is the facade; the others are its mixins, the state lives on it):
:mod:`.common` (constants, records), :mod:`.wire` (dispatch, TPDO decode, bursts, SDO),
:mod:`.supervision` (EMCY, heartbeat, feedback deadlines, the fault latch), :mod:`.startup`
(boot, configuration, reconfiguration after a reboot), :mod:`.sequences` (402 walks, fault
reset, homing, moves), :mod:`.cycle` (plan and send), :mod:`.facade` (the group, close).
"""

from cdcr_ctl.drives import epos
from cdcr_ctl.drives.epos import controlword_payload, parse_tpdo_feedback, target_payload
from cdcr_ctl.drives.group.common import (
    BOOT_TIMEOUT_S,
    FAULT_RESET_TIMEOUT_S,
    STATE_STEP_TIMEOUT_S,
    Feedback,
    GroupFault,
)

# Public names of the module before the split (reachable here as before):
from cdcr_ctl.drives.group.common import CLOSE_SDO_TIMEOUT_S as CLOSE_SDO_TIMEOUT_S
from cdcr_ctl.drives.group.common import CLOSE_SETTLE_S as CLOSE_SETTLE_S
from cdcr_ctl.drives.group.common import FAULT_TPDOS as FAULT_TPDOS
from cdcr_ctl.drives.group.common import FRAME_RING as FRAME_RING
from cdcr_ctl.drives.group.common import IDLE_PERIODS as IDLE_PERIODS
from cdcr_ctl.drives.group.common import IP_PREFILL_POINTS as IP_PREFILL_POINTS
from cdcr_ctl.drives.group.common import MOVE_TIMEOUT_S as MOVE_TIMEOUT_S
from cdcr_ctl.drives.group.common import NMT_COB_ID as NMT_COB_ID
from cdcr_ctl.drives.group.common import NMT_PRE_OPERATIONAL as NMT_PRE_OPERATIONAL
from cdcr_ctl.drives.group.common import NMT_RESET_COMMUNICATION as NMT_RESET_COMMUNICATION
from cdcr_ctl.drives.group.common import NMT_START as NMT_START
from cdcr_ctl.drives.group.common import SDO_TIMEOUT_S as SDO_TIMEOUT_S
from cdcr_ctl.drives.group.common import SEND_TIMEOUT_S as SEND_TIMEOUT_S
from cdcr_ctl.drives.group.common import SETPOINT_ACK_TIMEOUT_S as SETPOINT_ACK_TIMEOUT_S
from cdcr_ctl.drives.group.common import SYNC_COB_ID as SYNC_COB_ID
from cdcr_ctl.drives.group.common import TPDO_MISSES as TPDO_MISSES
from cdcr_ctl.drives.group.common import WATCHDOG_PERIOD_S as WATCHDOG_PERIOD_S
from cdcr_ctl.drives.group.common import format_frames as format_frames
from cdcr_ctl.drives.group.common import sdo_controlword_request as sdo_controlword_request
from cdcr_ctl.drives.group.facade import DriveGroup, open_drive_group

#: Kept for callers of earlier versions of this module.
rpdo_target_payload = target_payload
rpdo_controlword_payload = controlword_payload
parse_pvt_payload = epos.parse_pvt
configuration_writes = epos.configuration_writes
pdo_mapping_writes = epos.pdo_mapping_writes

__all__ = [
    "BOOT_TIMEOUT_S",
    "FAULT_RESET_TIMEOUT_S",
    "STATE_STEP_TIMEOUT_S",
    "DriveGroup",
    "Feedback",
    "GroupFault",
    "open_drive_group",
    "parse_tpdo_feedback",
]
