"""Sensing: the fixed camera (eq. 2), photogrammetry and the EKF (eqs. 1-7) and the
estimators that turn frames into the target's estimated state in the global frame (eqs. 11-12)."""
