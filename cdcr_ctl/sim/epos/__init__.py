"""Simulated maxon EPOS4/EPOS2 nodes on canopen's LocalNode, and their bus (in-process or slcan)."""
