"""What ``reset`` draws for an episode before any step, and the rules built on it alone.

An episode's target trajectory and the real period of every control step are drawn at reset from
the env's seeded generator, and kept only if the episode can be won (`draw_plans`, the one
place every env, recording and evaluation draws from). The time limit, the end of the last
possible step, how far the joints can have moved by a given time, and the physical-limit bound
are functions of that `EpisodePlan` alone, so
[`CaptureEnv`][capture_bench.envs.capture_env.CaptureEnv] and the batched
[`CaptureVectorEnv`][capture_bench.envs.vector_env.CaptureVectorEnv] share them here.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from capture_bench.sensing.camera import CameraModel
from capture_bench.sim import kinematics
from capture_bench.sim.target_motion import TargetTrajectory, sample_trajectory
from capture_bench.task.observation import TaskDescription
from capture_bench.task.physical_limit import PhysicalLimit, physical_limits
from capture_bench.task.scenarios import ControlConfig, Scenario

FloatArray = NDArray[np.float64]

MAX_PLACEMENT_TRIES = 1000
MAX_PLAN_DRAWS = 100  # plans drawn for one episode before no winnable one is an error
PLACEMENT_MARGIN = 0.1  # markers start inside the central 90% of the sensor's width and height
VIEW_CHECK_TIMES = (0.0, 1.0, 2.0, 3.0)  # s: ... and stay there on the true path at these times
# Sums of control periods carry rounding (10 x 0.05 > 0.5); "longer than lost_after" means longer
# by more than this, and the time limit is reached at this much before it, so the env, its
# recordings and the physical-limit check count the same steps.
TIME_SLACK = 1e-9  # s


def time_limit(control: ControlConfig) -> float:
    """The time at which an episode truncates, s (the episode limit, less the rounding slack)."""
    return control.episode_limit - TIME_SLACK


def place_target(
    scenario: Scenario,
    camera_model: CameraModel,
    features: FloatArray,
    rng: np.random.Generator,
) -> TargetTrajectory:
    """Draw trajectories until the start is reachable and above the floor, and the markers are
    well inside the image (``PLACEMENT_MARGIN``) at every ``VIEW_CHECK_TIMES``."""
    anchor = kinematics.forward_kinematics(kinematics.HOME)
    floor = -kinematics.L0
    for _ in range(MAX_PLACEMENT_TRIES):
        traj = sample_trajectory(scenario.target, rng, anchor, scenario.control.episode_limit)
        x0 = traj.position(0.0)
        if (
            x0[2] > floor + 0.05
            and kinematics.reachable(x0)
            and _stays_in_view(camera_model, features, traj)
        ):
            return traj
    raise RuntimeError(
        f"scenario {scenario.name!r}: no target start in view and in reach after "
        f"{MAX_PLACEMENT_TRIES} draws; check target.initial_offset and the camera pose"
    )


def _stays_in_view(model: CameraModel, features: FloatArray, traj: TargetTrajectory) -> bool:
    times = np.array(VIEW_CHECK_TIMES)
    rotated = np.einsum("nj,tij->tni", features, traj.rotations(times))
    points = (traj.position(times)[:, None, :] + rotated).reshape(-1, 3)
    return bool(model.visible(model.to_camera(points), margin=PLACEMENT_MARGIN).all())


def period_count(control: ControlConfig) -> int:
    """How many control periods `draw_periods` draws: enough for the longest episode
    (every step as short as the jitter allows), and one more."""
    shortest = control.period * (1.0 - control.period_jitter)
    return math.ceil(control.episode_limit / shortest) + 1


def draw_periods(control: ControlConfig, rng: np.random.Generator) -> FloatArray:
    """The real control period of every step the episode can have, s: t_s, or in
    ``period_jitter`` scenarios t_s (1 + jitter u) with u uniform in [-1, 1), drawn at reset so
    that the physical-limit bound sees the periods the steps will have."""
    n = period_count(control)
    if control.period_jitter == 0.0:
        periods = np.full(n, control.period)
    else:
        periods = control.period * (1.0 + control.period_jitter * rng.uniform(-1.0, 1.0, n))
    periods.flags.writeable = False  # shared with replays of the episode
    return periods


@dataclass(frozen=True, eq=False)
class EpisodePlan:
    """An episode as reset draws it: the scenario, the target's true trajectory and the real
    control period of every step it can have (s); ``bound``, the physical limit
    (`episode_bounds` under `describe_task`), as `draw_plans` computed it to
    keep the plan (None for a plan built otherwise: computed when asked)."""

    scenario: Scenario
    trajectory: TargetTrajectory
    periods: FloatArray
    bound: PhysicalLimit | None = None

    @classmethod
    def draw(
        cls,
        scenario: Scenario,
        camera_model: CameraModel,
        features: FloatArray,
        rng: np.random.Generator,
    ) -> EpisodePlan:
        """The next winnable episode of ``rng``: `draw_plans` of one generator."""
        (plan,) = draw_plans(scenario, camera_model, features, [rng])
        return plan

    def step_times(self) -> tuple[FloatArray, FloatArray]:
        """``(time, dt)`` of reset (0, t_s) and of every step up to the one that reaches the time
        limit, s: the times are the running sums a stepping env accumulates, bit for bit."""
        ends = np.cumsum(self.periods)
        n = int(np.searchsorted(ends, time_limit(self.scenario.control))) + 1
        times = np.concatenate(([0.0], ends[:n]))
        dts = np.concatenate(([self.scenario.control.period], self.periods[:n]))
        return times, dts

    def end(self) -> float:
        """When the last possible step ends, s: the time limit, or under ``period_jitter`` the end
        of the step that crosses it (a step truncates there)."""
        control = self.scenario.control
        if control.period_jitter == 0.0:
            return control.episode_limit
        ends = np.cumsum(self.periods)
        return float(ends[np.searchsorted(ends, time_limit(control))])

    def travel_time(self, times: FloatArray) -> FloatArray:
        """How long the joints can have moved at full rate by each time t, s: a step of real
        period dt moves a joint at most theta_dot_max min(dt, t_s) (the action's range is
        theta_dot_max t_s), spread evenly over the step as the capture test assumes."""
        periods = self.periods
        moves = np.minimum(periods, self.scenario.control.period)
        ends = np.cumsum(periods)  # t_j, the same sums as the steps' times
        step = np.minimum(np.searchsorted(ends, times), periods.size - 1)  # t_{j-1} < t <= t_j
        start = ends[step] - periods[step]
        moved_before = np.cumsum(moves) - moves
        return moved_before[step] + (times - start) / periods[step] * moves[step]

    def leaves_reach_before(self, t_end: float) -> bool:
        """Whether every episode of this plan ends ``unreachable`` on a step that ends before
        ``t_end``, so that no capture is possible by then.

        The env's own test, step by step, on the episode's real control periods: a step that ends
        at or after ``t_end`` may capture first.
        """
        if not math.isfinite(t_end):
            return False
        limit = self.scenario.lost_after + TIME_SLACK
        times = np.cumsum(self.periods)  # t_j, the same sums as the steps' times
        played = int(np.searchsorted(times, t_end, side="left"))  # the steps ending before t_end
        if played == 0:
            return False
        reach = kinematics.reachable(self.trajectory.states(times[:played])[0])
        out_for = 0.0
        for dt, inside in zip(self.periods[:played].tolist(), reach.tolist(), strict=True):
            out_for = 0.0 if inside else out_for + dt
            if out_for > limit:
                return True
        return False


def describe_task(scenario: Scenario) -> TaskDescription:
    """What an env of ``scenario`` publishes for agents: the arm, t_s and epsilon (3,), and with
    the rendered camera (which the arm can hide) the acquisition yaw; also the task the physical
    limit of a drawn plan is computed for."""
    arm = kinematics.ArmSpec()
    return TaskDescription(
        arm=arm,
        control_period=scenario.control.period,
        capture_tolerance=np.full(3, scenario.capture_tolerance),
        acquisition_yaw=acquisition_yaw(scenario, arm)
        if scenario.camera.mode == "rendered"
        else None,
    )


def acquisition_yaw(scenario: Scenario, arm: kinematics.ArmSpec) -> float:
    """The joint-1 angle that points the arm along the camera's horizontal line of sight, away
    from the camera (within joint 1's limits), rad: the arm's smallest profile in the image."""
    sight = np.subtract(scenario.camera.look_at, scenario.camera.position)
    yaw = float(np.arctan2(sight[1], sight[0]))
    return float(np.clip(yaw, arm.joint_lower[0], arm.joint_upper[0]))


def _same_task(a: TaskDescription, b: TaskDescription) -> bool:
    """Whether two descriptions give every plan the same physical limit (the arm and epsilon)."""
    arrays = ("joint_rate_limits", "joint_lower", "joint_upper", "home")
    return (
        a.arm.link_lengths == b.arm.link_lengths
        and all(np.array_equal(getattr(a.arm, k), getattr(b.arm, k)) for k in arrays)
        and np.array_equal(a.capture_tolerance, b.capture_tolerance)
    )


def draw_plans(
    scenario: Scenario,
    camera_model: CameraModel,
    features: FloatArray,
    rngs: Sequence[np.random.Generator],
) -> list[EpisodePlan]:
    """The next winnable episode of each generator: every episode can be captured in time.

    The rule: from its generator, an episode draws the trajectory (`place_target`), then
    the control periods (`draw_periods`), and computes the plan's physical limit
    (`episode_bounds` under `describe_task`). The plan is kept if that limit is finite:
    some joint-rate-limited motion of the arm captures the target before the time limit (and
    before it has left the arm's reach for longer than ``lost_after``). Otherwise the same
    generator draws a whole plan again (trajectory, then periods), and so on; after
    ``MAX_PLAN_DRAWS`` plans with no finite limit, ``RuntimeError`` names the scenario. Only
    then do the episode's other draws (the camera's noise and drop-outs) follow from the
    generator. A seed's episode is therefore one function of the scenario and the seed in every
    env, recording and evaluation, and a seed whose first plan is winnable keeps it (the
    generator stands where it stood without the rule).

    The kept plan carries its limit (`EpisodePlan.bound`), which `episode_bounds`
    gives again without computing it, so an episode's limit is computed once. The generators'
    plans are drawn in turn and their limits computed together, a round per redraw: each
    generator's plan is what it alone would draw (the limits of many plans are each one's own,
    `physical_limits`).
    """
    task = describe_task(scenario)
    plans: list[EpisodePlan | None] = [None] * len(rngs)
    pending = list(range(len(rngs)))
    for _ in range(MAX_PLAN_DRAWS):
        if not pending:
            break
        drawn = []
        for i in pending:
            trajectory = place_target(scenario, camera_model, features, rngs[i])
            drawn.append(EpisodePlan(scenario, trajectory, draw_periods(scenario.control, rngs[i])))
        left = []
        for i, plan, bound in zip(pending, drawn, _compute_bounds(drawn, task), strict=True):
            if math.isfinite(bound.time):
                plans[i] = dataclasses.replace(plan, bound=bound)
            else:
                left.append(i)
        pending = left
    if pending:
        raise RuntimeError(
            f"scenario {scenario.name!r}: no episode the arm can win (a finite physical limit "
            f"before the time limit) in {MAX_PLAN_DRAWS} draws; check target.initial_offset, "
            "target.speed and control.episode_limit"
        )
    return [plan for plan in plans if plan is not None]


def episode_bounds(
    plans: Sequence[EpisodePlan], description: TaskDescription
) -> list[PhysicalLimit]:
    """The physical-limit bound of each episode (DESIGN.md), computed together: the earliest
    entry into the capture envelope from which it can hold for the scenario's ``capture.hold``,
    plus that hold (see `capture_bench.task.physical_limit`); ``inf`` when that is after
    the episode's last step ends, or when the target leaves the arm's reach for longer than
    ``lost_after`` before it.
    A plan that carries its bound (`draw_plans`) gives it without a computation where
    ``description`` is `describe_task`'s (the same arm and epsilon)."""
    if not plans:
        return []
    carried = [
        plan.bound
        if plan.bound is not None and _same_task(description, describe_task(plan.scenario))
        else None
        for plan in plans
    ]
    todo = [plan for plan, bound in zip(plans, carried, strict=True) if bound is None]
    computed = iter(_compute_bounds(todo, description) if todo else [])
    return [next(computed) if bound is None else bound for bound in carried]


def _compute_bounds(
    plans: Sequence[EpisodePlan], description: TaskDescription
) -> list[PhysicalLimit]:
    """`episode_bounds` of plans that carry none, computed together."""
    arm = description.arm
    control, capture = plans[0].scenario.control, plans[0].scenario.capture
    ends = [plan.end() for plan in plans]
    limits = physical_limits(
        [plan.trajectory.position for plan in plans],
        arm.home,
        arm.joint_rate_limits,
        arm.joint_lower,
        arm.joint_upper,
        description.capture_tolerance,
        horizons=ends,
        period=control.period,
        travel_times=[plan.travel_time if control.period_jitter else None for plan in plans],
        hold=capture.hold,
        v_max=capture.v_max,
        target_velocities=[plan.trajectory.velocity for plan in plans],
    )
    hold = capture.hold
    out = []
    for plan, end, limit in zip(plans, ends, limits, strict=True):
        time = limit.time  # the envelope's: entry plus the hold; inf stays inf
        if time > end or plan.leaves_reach_before(time):
            out.append(PhysicalLimit(math.inf, None, hold))
        else:
            out.append(PhysicalLimit(time, limit.theta, hold))
    return out
