"""canopen's own, unmodified RemoteNode/BaseNode402 against the simulated EPOS4: the simulator
speaks plain CiA 301/402 (its object dictionary as an EDS, factory PDO mapping), not only our
driver's dialect."""

from __future__ import annotations

import threading
import time

import canopen
from canopen.objectdictionary import export_od
from drivesim import channel, wait_until

from cdcr_ctl.drives.cia402 import State
from cdcr_ctl.sim.epos.od import build_od
from cdcr_ctl.sim.epos.rig import SimDriveBus


def settled(n) -> bool:
    """No more SYNCs arriving at node ``n`` (those in flight have been processed)."""
    before = n.sync_count
    time.sleep(0.05)
    return n.sync_count == before


def test_stock_basenode402_reads_identity_enables_and_reads_position(tmp_path):
    ch = channel()
    sim = SimDriveBus([(1, "epos4")], "virtual", ch).start()
    eds = tmp_path / "sim-epos4.eds"
    export_od(build_od(1, "epos4"), str(eds), doc_type="eds")  # the simulator's OD as an EDS
    net = canopen.Network()
    net.connect(interface="virtual", channel=ch)
    try:
        node = canopen.BaseNode402(1, str(eds))
        # canopen's own timeouts (class attributes), generous for a loaded CI machine
        node.TIMEOUT_CHECK_TPDO = node.TIMEOUT_SWITCH_STATE_SINGLE = 2.0
        node.TIMEOUT_SWITCH_STATE_FINAL = node.TIMEOUT_SWITCH_OP_MODE = 5.0
        node.sdo.RESPONSE_TIMEOUT = 2.0
        net.add_node(node)
        booted = threading.Thread(target=node.nmt.wait_for_bootup, args=(5,))
        booted.start()
        time.sleep(0.05)
        node.nmt.state = "RESET COMMUNICATION"
        booted.join()
        assert node.nmt.state == "PRE-OPERATIONAL"

        assert node.sdo[0x1000].raw == 0x00020192  # CiA 402 servo drive
        assert node.sdo[0x1018][1].raw == 0xFB  # maxon
        assert node.sdo[0x1018][2].raw == 0x65520000
        assert node.sdo["Manufacturer device name"].raw == "EPOS4"  # segmented upload

        node.setup_402_state_machine(read_pdos=True)  # reads the factory PDO mapping by SDO
        assert 0x6041 in node.tpdo_values and 0x6040 in node.rpdo_pointers
        node.op_mode = "CYCLIC SYNCHRONOUS POSITION"  # checks 0x6502, confirms by 0x6061
        assert node.op_mode == "CYCLIC SYNCHRONOUS POSITION"
        node.nmt.state = "OPERATIONAL"
        net.sync.start(0.002)  # canopen's own SYNC producer
        node.state = "OPERATION ENABLED"  # canopen's 402 walk over the RPDO controlword
        assert node.state == "OPERATION ENABLED"
        assert sim.node(1).state is State.OPERATION_ENABLED

        sim.node(1).displace(321)  # move the motor: the position loop pulls it back
        assert wait_until(lambda: abs(sim.node(1).position_counts) <= 1)
        net.sync.stop()  # the simulated drive's time stands still without SYNC
        assert wait_until(lambda: settled(sim.node(1)))
        # The TPDO holds the position sampled at the last SYNC, before that SYNC's period ran
        # (one cycle of lag, as on the drive); at rest the last period moves it at most 1 count.
        assert wait_until(
            lambda: abs(node.tpdo_values.get(0x6064, 99) - sim.node(1).position_counts) <= 1
        )
        assert node.sdo[0x6064].raw == sim.node(1).position_counts  # by SDO: the live value

        net.sync.start(0.002)
        node.state = "SWITCH ON DISABLED"
        assert sim.node(1).state is State.SWITCH_ON_DISABLED
    finally:
        net.sync.stop()
        net.disconnect()
        sim.stop()
