"""CANopen drive layer for maxon EPOS4/EPOS2: counts and modes, no robot knowledge.

- :mod:`~cdcr_ctl.drives.canbus`   open the python-can bus a config names
- :mod:`~cdcr_ctl.drives.cia402`   CiA 402 states, controlwords, modes (pure)
- :mod:`~cdcr_ctl.drives.emcy`     EMCY codes as text (one table)
- :mod:`~cdcr_ctl.drives.busload`  does the cyclic PDO set fit the SYNC period?
- :mod:`~cdcr_ctl.drives.group`    all drives of a rig: SDO configuration, RPDO + SYNC cycles,
  TPDO feedback, EMCY/heartbeat supervision, enable/disable/quick stop, homing
"""
