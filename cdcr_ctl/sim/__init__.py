"""The simulated rig: EPOS nodes, load cells, tracker, truth physics (never imported by
production code)."""
