"""Physics the designs share: a cable on a curved surface and the play between drive and cable.

numpy/scipy only: no I/O, no clocks.

- :mod:`~cdcr_ctl.model.shared.capstan`   improved capstan for pulleys (Qi et al. 2023 eq. 25-32)
- :mod:`~cdcr_ctl.model.shared.friction`  capstan friction in the disk holes and the stick/slide
  state (Qi et al. 2023 eq. 16-24)
- :mod:`~cdcr_ctl.model.shared.deadzone`  lost motion: the play operator and its rate-bounded
  inverse (Yang et al. 2022 eq. 13-17)
"""
