"""CANopen drive layer for maxon EPOS4/EPOS2: counts and modes, no robot knowledge.

- :mod:`~cdcr_ctl.drives.canbus`    open the python-can bus a config names
- :mod:`~cdcr_ctl.drives.cia402`    CiA 402 states, controlwords, modes (pure)
- :mod:`~cdcr_ctl.drives.epos`      object indices, PDO layout per mode, SDO configuration, PDO
  payloads (pure)
- :mod:`~cdcr_ctl.drives.emcy`      EMCY codes of EPOS4/EPOS2 as text (one table)
- :mod:`~cdcr_ctl.drives.busload`   does the cyclic PDO set fit the SYNC period?
- :mod:`~cdcr_ctl.drives.heartbeat` heartbeat consumer on the master (pure bookkeeping)
- :mod:`~cdcr_ctl.drives.group`     all drives of a rig: boot, configuration, RPDO + SYNC cycles,
  TPDO feedback, EMCY/heartbeat supervision, enable/disable/quick stop/halt, homing, profile moves
"""
