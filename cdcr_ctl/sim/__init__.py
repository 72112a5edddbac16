"""The simulated rig: EPOS nodes, load cells, tracker and truth physics. Never imported by production code."""
