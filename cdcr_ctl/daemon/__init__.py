"""The daemon: owns the bus and sensors, runs the loop, serves the control socket."""
