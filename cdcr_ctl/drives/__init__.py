"""CANopen drive layer for maxon EPOS4/EPOS2: counts and modes, no robot knowledge.

- :mod:`~cdcr_ctl.drives.canbus`    open the python-can bus a config names
- :mod:`~cdcr_ctl.drives.cia402`    CiA 402 states, controlwords, modes (pure)
- :mod:`~cdcr_ctl.drives.epos`      object indices, PDO layout per mode, SDO configuration, PDO
  payloads (pure)
- :mod:`~cdcr_ctl.drives.emcy`      EMCY codes of EPOS4/EPOS2 as text (one table)
- :mod:`~cdcr_ctl.drives.busload`   does the cyclic PDO set fit the SYNC period?
- :mod:`~cdcr_ctl.drives.heartbeat` heartbeat consumer on the master (pure bookkeeping)
- :mod:`~cdcr_ctl.drives.limits`    what an EPOS4/EPOS2 accepts (maxon's device descriptions):
  object types, access, ranges; the one write check (pure)
- :mod:`~cdcr_ctl.drives.plan`      every planned SDO write checked before the first frame, against
  the drive's ``eds:`` file or the shipped table (ConfigError naming file, key, object)
- :mod:`~cdcr_ctl.drives.diagnosis` a faulted drive's 0x603F and 0x1003 in words (pure)
- :mod:`~cdcr_ctl.drives.scan`      which nodes are on a bus (0x1000, 0x1018, 0x1008) vs the config
- :mod:`~cdcr_ctl.drives.group`     all drives of a rig: boot, configuration, RPDO + SYNC cycles,
  TPDO feedback, EMCY/heartbeat supervision, enable/disable/quick stop/halt, homing, profile moves
"""
