"""Lock-step simulation: the simulated rig and the controller's I/O on one simulated clock
(:mod:`.rig`), deterministic and as fast as the CPU allows."""
