"""The real-time loop and what it follows: setpoint sources (trajectories), supervisor, timing."""
