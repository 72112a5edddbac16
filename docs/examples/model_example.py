"""The loop's model of the Qi et al. 2023 rig, scripted: cable commands for one pose.

Run from the repository: ``python docs/examples/model_example.py``.
"""

import math

import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model

cfg = load_rig_config("config/qi2023.yaml")
model = build_model(cfg)  # CCDiskModel for a cc_disk rig: every effect of the config on

psi = np.array([[math.radians(45.0), 0.0]])  # one segment: bend 45 deg in the plane phi = 0
q_nominal = model.q_nominal(psi)  # ideal inverse kinematics, mm of cable pulled in
state = model.new_state()  # friction and dead-zone memories, carried from cycle to cycle
q_model = model.q_command(psi, q_nominal, state, "model", None)  # q~ = q + delta (eq. 37)

print("tip (mm, base frame):", np.round(model.tip(psi), 3))
for name, qn, qc in zip((c.name for c in cfg.robot.cables), q_nominal, q_model, strict=True):
    print(f"{name}: geometry {qn:+.3f} mm, with compensation {qc:+.3f} mm (delta {qc - qn:+.3f})")
