"""The episode engine: what an environment is made of, whatever the number of episodes it steps.

A stage between the rules of the benchmark (`capture_bench.task`) and the gymnasium environments
(`capture_bench.envs`), which are built on it: `capture_bench.engine.task` holds the task of a
scenario as an env plays it (`CaptureTask`: the scenario, its published description, the step
rule, the camera and the spaces of one episode) and `check_actions`, the one rule for an action's
validity; `capture_bench.engine.cache` holds the target sides and physical-limit bounds already
computed, kept by (scenario, seed) (`EpisodeCache`); `capture_bench.engine.view` the privileged
view of one episode (`PrivilegedView`: the oracle's API, the same on both envs);
`capture_bench.engine.engine` steps N episodes as rows (`EpisodeEngine`) from the arm's side
(`capture_bench.engine.arm`), the target's side (`capture_bench.engine.sides`, filling
`capture_bench.engine.tracks`) and the step rule. It imports the task, sensing and simulation
stages, never an environment.
"""
