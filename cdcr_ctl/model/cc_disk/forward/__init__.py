"""Forward static model: actuator displacements -> pose and tensions, with friction memory.

Unknowns: the bending vectors x (2S, rad), the anchor tensions T (K, N) and the mobilised friction
fractions s (K). Equations (all effects of :class:`~cdcr_ctl.model.cc_disk.params.Effects`
switchable):

* moment balance, 2S (statics.py, moment-vector form of Qi et al. 2023 eq. 9-15)
* cable compatibility, K: q_act_k = q_geom_k(x) + delta_k(x, T_k, s_k)   (eq. 33-37, material
  conservation along the whole cable)
* friction, K (friction.py): stuck cable: w_k = w_prev_k and |s_k| <= 1; sliding: s_k = +-1 with
  sign(w_k - w_prev_k) = s_k. A slack cable (T would be < 0) has T_k = 0 and no compatibility.

solved by Newton's method (finite-difference columns for x, analytic/cheap columns for T and s,
the Jacobian reused while convergence is fast, a trust region on the pose) inside an active-set
loop over the cable modes. A cable coming out of slack carries no friction memory: it re-engages
sliding in the pull direction. With rigid cables (elongation off) the pose comes
from the kinematics alone (eq. 4 is linear in x: least squares), the tensions from the inverse
statics, and the friction state from the direction of motion (the paper's rule).

:class:`ForwardStepper` carries the friction state and the last solution from call to call (warm
start): the simulator's truth. Its :class:`Effects` and :class:`RobotParams` may differ from the
controller's.
"""

from cdcr_ctl.model.cc_disk.forward.solver import (
    FREE,
    SLACK,
    SLIDE,
    STICK,
    SUBSTEP_LEVELS,
    ForwardModel,
    ForwardResult,
)
from cdcr_ctl.model.cc_disk.forward.stepper import ForwardStepper, Replay, replay

__all__ = [
    "FREE",
    "SLACK",
    "SLIDE",
    "STICK",
    "SUBSTEP_LEVELS",
    "ForwardModel",
    "ForwardResult",
    "ForwardStepper",
    "Replay",
    "replay",
]
