"""Pure numerics of warpbridge: the generalized Bouc-Wen tendon-sheath model.

No I/O lives here. Names follow the paper (Lee et al., MSSP 85 (2017)):
``w`` warp angle (deg), ``u`` tendon travel at the servo (mm, + = pull),
``z`` the hysteretic state (mm of tendon, since ``az`` multiplies it).
"""
