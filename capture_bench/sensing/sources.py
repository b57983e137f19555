"""The observation sources: what stands between the target's true state and the agent.

``ekf`` (photogrammetry initialising the EKF, the paper's section 2), ``photogrammetry`` (the raw
pose of every frame, an ablation) and ``truth`` (the true state, noise-free) are the estimator
sources (`SOURCES`). ``pixels`` (`PIXELS`) is no estimator: the agent sees the camera's
image and the arm's own state (`capture_bench.sensing.workspace_image`), while the scenario's
estimator still runs for ``info`` and the metrics. Defined here alone, with no heavy imports, so
that scenario files, the estimators, the envs and the CLIs share one list.
"""

SOURCES = ("ekf", "photogrammetry", "truth")
PIXELS = "pixels"
ENV_OBSERVATIONS = (*SOURCES, PIXELS)  # what an env's ``observation_source`` may be
