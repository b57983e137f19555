"""Simulation: the arm's kinematics (paper eqs. 8-9, Table 1), the pybullet world, the
target's true motion and rotation helpers. Imports nothing from sensing, task or envs."""
