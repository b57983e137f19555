"""What ``CaptureEnv`` and ``CaptureVectorEnv`` both give their users about their task.

Each env owns a `capture_bench.engine.task.CaptureTask` (``env.task``); `TaskAccess` gives
both envs the same public names for it (``scenario``, ``description``, ``rule``,
``reward_mode``) and the training curriculum's two levers, `TaskAccess.set_capture_hold` and
`TaskAccess.set_capture_tolerance`. `Observation` (the engine's) is the type of what they
observe.
"""

from __future__ import annotations

from typing import Any

from capture_bench.engine.task import CaptureTask, Observation
from capture_bench.task.observation import TaskDescription
from capture_bench.task.scenarios import Scenario
from capture_bench.task.step_rule import StepRule

__all__ = ["Observation", "TaskAccess"]


class TaskAccess:
    """The public names of an env's `CaptureTask` (``self.task``), the same on both envs.

    Attributes (read-only): ``scenario``, ``description``, ``rule``, ``reward_mode``: the
    task's.
    """

    task: CaptureTask

    @property
    def scenario(self) -> Scenario:
        """The env's scenario (its estimator source replaced if the env was given one)."""
        return self.task.scenario

    @property
    def description(self) -> TaskDescription:
        """What agents may know: the arm's constants, t_s and epsilon."""
        return self.task.description

    @property
    def rule(self) -> StepRule:
        """The step rule the env applies."""
        return self.task.rule

    @property
    def reward_mode(self) -> str:
        """``"dense"``, ``"sparse"`` or ``"shaped"``."""
        return self.task.reward_mode

    def set_capture_hold(self, hold: float) -> None:
        """Ask a capture to hold ``hold`` s (0: the first entry captures) instead of the
        scenario's ``capture.hold`` from the next step on: a training curriculum's lever
        (`capture_bench.training.callbacks.HoldCurriculum`), never an evaluation's. The
        recorded physical limit stays the scenario's."""
        self.task.rule.set_hold(hold)

    def set_capture_tolerance(self, tolerance: Any) -> None:
        """Count a capture at ``tolerance`` (m, a number or (3,)) instead of the scenario's
        epsilon from the next step on: a training curriculum's lever
        (`capture_bench.training.callbacks.ToleranceCurriculum`), never an evaluation's.
        The recorded physical limit stays the scenario's."""
        self.task.rule.set_tolerance(tolerance)
