"""Sensor protocol layers: load cells, tip tracker, attitude sensors, joystick.

Nothing here knows about robots: a load cell is newtons, a tracker is a pose in its own frame.
Transports are injected (a pyserial port, a socket) so tests run against simulated peers on a
pseudo-terminal. :mod:`cdcr_ctl.sensors.sample` holds the timestamped-sample types they share.
"""
