"""The observation sources: what stands between the target's true state and the agent.

``ekf`` (photogrammetry initialising the EKF, the paper's section 2), ``photogrammetry`` (the raw
pose of every frame, an ablation) and ``truth`` (the true state, noise-free). Defined here alone,
with no heavy imports, so that scenario files, the estimators and the CLIs share one list.
"""

SOURCES = ("ekf", "photogrammetry", "truth")
