"""``CaptureEnv``: the gymnasium environment, the N = 1 case of the episode engine.

An episode is one row of a `capture_bench.engine.engine.EpisodeEngine`, the engine
[`CaptureVectorEnv`][capture_bench.envs.vector_env.CaptureVectorEnv] steps N rows of: the arm's
side (rate and joint limits, forward kinematics, collisions), the target's side (trajectory,
camera eq. 2, estimator eqs. 3-12: live row by row, recorded at reset and replayed, or rendered;
`capture_bench.engine.sides`) and the rules of a step (capture, eq. 20 along the arc; failures;
rewards; ``info``; the observation, eq. 13: `capture_bench.task.step_rule.StepRule`), the same
code. What both envs are made of is `capture_bench.engine.task.CaptureTask`, the curriculum's
levers `capture_bench.envs.core.TaskAccess`'s. What this module adds: gymnasium's single-env
API and ``info``, rendering, and the privileged interface the oracle uses
(`capture_bench.engine.view.PrivilegedView`).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from capture_bench.engine.arm import ArmSide
from capture_bench.engine.cache import DEFAULT_EPISODE_CACHE, EpisodeCache, EpisodeKey
from capture_bench.engine.engine import EpisodeEngine
from capture_bench.engine.sides import EpisodeDraw, RenderedSides, target_sides
from capture_bench.engine.task import CaptureTask, check_actions
from capture_bench.engine.view import PrivilegedView
from capture_bench.envs.core import Observation, TaskAccess
from capture_bench.sensing.rendered_sensor import SceneEpisode
from capture_bench.task.physical_limit import PhysicalLimit
from capture_bench.task.recording import RecordedEpisode
from capture_bench.task.scenarios import Scenario
from capture_bench.task.step_rule import FAILURES, scalar_info

__all__ = ["FAILURES", "CaptureEnv"]
_ALL = slice(None)  # the single env's one episode, as rows of the step rule
_ROW = np.zeros(1, dtype=np.intp)  # the same, as an index array


def _check_display(render_mode: str | None) -> None:
    """``ValueError`` where ``render_mode="human"`` cannot open its window: pybullet's GUI is an X11
    window on Linux and the other Unix systems but macOS, and without ``DISPLAY`` its connection
    ends the process (exit status 1, nothing printed)."""
    if render_mode != "human" or os.name != "posix" or sys.platform == "darwin":
        return
    if not os.environ.get("DISPLAY"):
        raise ValueError(
            'render_mode="human" opens a pybullet window, which needs an X display, and '
            'DISPLAY is not set (a headless machine?); use render_mode="rgb_array" for images '
            "(render() returns them; gymnasium.wrappers.RecordVideo saves a video), or run under "
            "a display (e.g. xvfb-run)"
        )


def _check_render_size(size: Any) -> tuple[int, int]:
    """``size`` as (width, height) in pixels, or ``ValueError`` saying what is valid."""
    try:
        width, height = size
    except (TypeError, ValueError):
        width = height = None
    if not all(
        isinstance(n, (int, np.integer)) and not isinstance(n, bool) and n >= 1
        for n in (width, height)
    ):
        raise ValueError(
            f"render_size must be (width, height), two whole numbers >= 1; got {size!r}"
        )
    return int(width), int(height)


class CaptureEnv(TaskAccess, PrivilegedView, gym.Env):
    """Capture a drifting or tumbling target with the 3-joint arm of Dong & Zhu (2016).

    ## Description
    The arm (paper Table 1) starts at home, Θ = (0, 90°, 0). A non-cooperative target moves along
    a trajectory drawn from the scenario (drift, circular, tumbling, evasive). The agent never
    sees the target: a fixed camera (eq. 2) images four feature points, and photogrammetry
    initialises an extended Kalman filter (eqs. 3–7) whose estimate, in the global frame
    (eqs. 11–12), is observed. Capture is eq. 20 on the *true* target position, tested over the
    whole step along the end-effector's arc. A scenario with ``capture.hold`` = h > 0 s (``grasp``)
    asks for more: eq. 20 must hold without a break for h s (a gripper closing), and the capture
    is when the hold completes, entry + h, possibly mid-step; leaving the tolerance box before
    (also within a step, along the arc) restarts the clock at the next entry.

    ## Action Space
    ``Box(-1, 1, (3,), float32)``: ``ΔΘ_i = a_i · θ̇_max,i · t_s`` rad, θ̇_max = (10.304, 0.412,
    0.412) rad/s. The world clips every increment to ``θ̇_max,i · dt`` of the real period and to the
    joint limits, whatever the agent asks. Actions outside [-1, 1] (however large) are clipped.
    An action that is not a real number array of shape (3,) (a list or tuple of numbers is fine,
    any int or float dtype), or that holds a NaN or an infinity, raises ``ValueError`` naming the
    bad entry, and the step is not taken. Non-finite actions are refused rather than zeroed or
    clipped: a NaN from a policy means a diverged network, and a benchmark that quietly turned
    it into "hold still" would score the broken policy; Gymnasium's ``Box.contains`` refuses
    them too. [`CaptureVectorEnv`][capture_bench.envs.vector_env.CaptureVectorEnv] applies the same
    rule
    (`capture_bench.engine.task.check_actions`) to its (num_envs, 3) actions.

    ## Observation Space
    ``Box(-10, 10, (16,), float32)``, each entry scaled to order one
    (``capture_bench.task.observation.decode_observation`` undoes it):

    | index | quantity (global frame)                       | unit | scale   |
    |-------|-----------------------------------------------|------|---------|
    | 0–2   | estimated capture point X̂_T                   | m    | 1 m     |
    | 3–5   | estimated target velocity                     | m/s  | 0.1 m/s |
    | 6–8   | end-effector position X_E                     | m    | 1 m     |
    | 9–11  | joint angles Θ                                | rad  | π       |
    | 12–14 | predicted relative vector X̂_T + Ẋ̂_T t_s − X_E | m    | 0.5 m   |
    | 15    | last real control period dt                   | s    | t_s     |

    While the estimator has no estimate yet (e.g. during camera latency, or while the arm hides
    the markers), the target entries repeat the end-effector position with zero velocity; with
    the rendered camera ``description.acquisition_yaw`` says where joint 1 clears the line of
    sight (`capture_bench.agents.acquisition`).

    With ``observation_source="pixels"`` the agent sees no estimate but
    ``Dict(image=Box(0, 255, (3, H, W), uint8), state=Box(-10, 10, (7,), float32))``:
    ``image`` is the camera's view of a crop around the workspace (the arm at its joints, the
    target at its true pose with its grey block and 10 mm markers), rendered at ``image_size``
    (W, H) = (84, 84) by default (`capture_bench.sensing.workspace_image`: which crop, how
    it is sampled); ``state`` is what the arm knows without vision:

    | index | quantity (global frame)     | unit | scale |
    |-------|-----------------------------|------|-------|
    | 0–2   | joint angles Θ              | rad  | π     |
    | 3–5   | end-effector position X_E   | m    | 1 m   |
    | 6     | last real control period dt | s    | t_s   |

    The scenario's estimator still runs: ``info`` and the metrics are the same as with it.

    ## Rewards
    The step's reward is the sum of its terms, each also in ``info`` under its name
    (``capture_bench/task/rewards.py``). d_prev, d: true distance ||X_E − X_T|| before and after
    the step, m; Φ(d) = −ln(1 + d / 1 mm); v: the end-effector's instantaneous speed relative to
    the capture point at the step's end, ``|J(Θ) Θ̇ − Ẋ_T|`` (``info["relative_speed"]``), m/s;
    c: the closest approach of X_E − X_T during the step (on the straight segment between its
    ends), m; v_ref: the scenario's ``capture.v_max``, m/s.

    | term            | formula                            | units      | when                   |
    |-----------------|------------------------------------|------------|------------------------|
    | reward_progress | 10 (d_prev − d)                    | 10 per m   | dense: every step      |
    | reward_shaping  | 0.99 Φ(d) − Φ(d_prev)              | –          | shaped: every step     |
    | reward_time     | −0.01                              | per step   | dense, shaped: always  |
    | reward_speed    | −max(0, v − v_ref) · exp(−c/10 mm) | 1 per m/s  | dense, shaped: v_max set |
    | reward_capture  | +5 (sparse: +1)                    | –          | the step that captures |
    | reward_failure  | −5                                 | –          | a failure but timeout  |

    ``reward="dense"`` (default): ``reward_progress``, ``reward_time``, ``reward_speed``,
    ``reward_capture``, ``reward_failure``. ``reward="sparse"``: ``reward_capture`` alone (1 on
    capture, else 0). ``reward="shaped"``: dense with ``reward_progress`` replaced by
    potential-based shaping, ``reward_shaping``, which resolves the last millimetre.
    ``reward_speed`` charges a pass through the target at speed (a collision, not a capture) on
    the step that passes it, wherever that step ends, the capturing step included, so that
    arriving slow pays more than flying through (beyond 0.2 m its weight, below 2.1e-9, is taken
    as 0); it is not shaping and changes which policies are optimal, on purpose. A scenario
    without a speed bound (``capture.v_max: null``: the paper's eq. 20, any speed) has no
    charge: ``reward_speed`` is 0 there, as the rule asks nothing of the speed.

    ## Starting State
    Home pose. The capture point starts ``target.initial_offset`` m from the home end-effector in a
    uniformly drawn direction, redrawn until it is inside the joint-limited workspace and above the
    floor, and its four markers are inside the central 90% of the image at t = 0, 1, 2 and 3 s.
    Orientation, velocity, tumble and path are drawn from the scenario's ranges with
    ``self.np_random``, then the real control period of every step (``period_jitter``).

    ## Episode End
    Terminates on capture (``info["is_success"]``; with a hold, when the hold completes) or a
    failure (also during a hold that has not completed): ``collision`` (arm with floor,
    base or itself), ``target_lost`` (no usable frame for ``lost_after`` s: out of view, behind the
    lens, dropped, or the estimator diverged; never with the ``truth`` source), ``unreachable``
    (the capture point outside the arm's joint-limited reach for ``lost_after`` s). Truncates at
    ``control.episode_limit`` s of *simulated* time with failure ``timeout``. The env truncates
    itself, not a ``TimeLimit`` wrapper, because the limit is in seconds and the control period
    varies in some scenarios.

    ## Info
    Every step: ``is_success``, ``failure`` (None or one of ``FAILURES``), ``capture_time`` (s:
    when the capture completed), ``capture_time_estimated`` (s: first time the same test, hold
    included, completed on the *estimated* position, as the paper's hardware could only judge),
    ``time``, ``dt``, ``distance`` (true ||X_E − X_T|| at the step's end, m), ``relative_speed``
    (the end-effector's instantaneous speed relative to the capture point at the step's end,
    ``|J(Θ) Θ̇ − Ẋ_T|``, m/s; the joint rates are constant within a step), on the step that
    captures (None on the others) ``distance_at_capture`` (true ||X_E − X_T|| at the capture
    instant, m), ``relative_speed_at_capture`` (the same relative speed then, m/s) and
    ``relative_speed_max_over_hold`` (its largest from the captured stay's entry to the capture,
    m/s, sampled along each step at the speed test's points and the stay's ends, to 2e-4 m/s;
    with no hold, ``relative_speed_at_capture``), ``estimate_position_error``,
    ``estimate_velocity_error``, ``estimate_nees``, ``saturated``, ``clipped``, ``path_length``,
    ``target_visible``, ``estimator_status``, ``reward_*``. At the end:
    ``physical_limit_time`` (s; the earliest time eq. 20 can hold plus the hold; ``inf`` when that
    is after the time limit, or the target leaves the arm's reach for longer than ``lost_after``
    before it).

    ## Arguments
    ``scenario``: a shipped name (``capture_bench.task.scenarios.list_scenarios()``), a YAML path
    or a ``Scenario``. ``observation_source``: what the agent observes: an estimator source,
    ``"ekf"``, ``"photogrammetry"`` or ``"truth"`` (default: the scenario's), or ``"pixels"``
    (the image and the arm's state; the scenario's estimator runs for ``info``); anything else:
    ``ConfigError`` (a ``ValueError``). ``image_size``: with ``"pixels"``, the image's (width,
    height), pixels, default None: (84, 84); two whole numbers from 1 to 924 (the largest crop
    of the shipped camera), else ``ValueError``; given with any other observation source,
    ``ConfigError`` (it sizes nothing there). ``frame_stack`` (k, 1-16, default 1),
    ``ee_crop`` (n, 0-256 pixels, default 0: none), ``ee_crop_scale`` (c, 1-11 sensor pixels a
    crop pixel, default 1: full density), ``image_supersample`` (m, 1-11, default 1: point
    sampling) and ``ee_crop_supersample`` (the crop's m, the same): with ``"pixels"``, the last
    k images stacked along the channels (oldest first; an episode starts with k copies of its
    first), a second image ``ee_image`` of n x n pixels centred on the end-effector's
    projection, and each pixel the mean of m x m samples
    (`capture_bench.sensing.workspace_image`); None: the default; out of range,
    ``ValueError``; given with another source, ``ConfigError``. ``reward``: ``"dense"``,
    ``"sparse"`` or ``"shaped"``. ``render_mode``: ``"rgb_array"`` or ``"human"`` (a pybullet
    window: it needs a display; on Linux without ``DISPLAY``, ``ValueError`` at construction,
    suggesting ``"rgb_array"``). ``render_size``: (width, height) of the image
    ``render()`` returns, pixels, default (640, 480) (a video of many episodes asks for less:
    pybullet's TinyRenderer's cost grows with the pixels; ``benchmarks/bench_render.py`` times
    frames of two sizes); two whole numbers >= 1, else ``ValueError``. ``reuse_target_side``:
    when True, ``reset(seed=s)`` records the target's side of the whole episode up to the time
    limit at once (trajectory, control periods, camera frames, estimates: a
    `RecordedEpisode`, none of which depends on the actions)
    and keeps it in ``episode_cache`` by (scenario, s); a later ``reset(seed=s)`` replays it instead
    of computing it again. Every observation, reward and ``info`` is identical to a run without it;
    an evaluation that runs many agents on the same seeds saves the camera and estimator work of all
    but the first. An unseeded reset is recorded the same way but not kept. After any reset
    ``np_random`` stands where the recording left it (the time limit), so the episodes that follow a
    seeded reset are the same whatever the actions, though after the first they are not the ones a
    plain env gives (it advances ``np_random`` by the steps actually taken);
    [`CaptureVectorEnv`][capture_bench.envs.vector_env.CaptureVectorEnv] gives exactly these
    episodes. Default
    False: each reset pays for the whole horizon. ``episode_cache``: the
    `EpisodeCache` that keeps recorded target sides and
    physical-limit bounds by (scenario, seed); default the process-wide
    ``capture_bench.engine.cache.DEFAULT_EPISODE_CACHE`` (``clear()`` empties it).
    ``render_view``: what ``render()`` shows: ``"scene"`` (pybullet's view of the world with the
    target's and end-effector's traces) or ``"camera"`` (the rendered camera's own image scaled to
    ``render_size``, with the markers found, the missing ones and the estimated capture point
    drawn on it; scenarios with ``camera.mode: rendered`` only, and their default).

    ## Rendered camera
    With ``camera.mode: rendered`` the frames are pybullet images of the whole scene, the arm
    included, and the markers are found in their pixels
    (`capture_bench.sensing.scene_camera`): the target's side depends on the actions, so it
    is computed step by step (``reuse_target_side`` then keeps, by seed, what the camera saw of
    the target alone, and renders again only the frames the arm may reach).

    ## Version History
    * v0: initial release.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 20}

    def __init__(
        self,
        scenario: str | Path | Scenario = "paper",
        *,
        observation_source: str | None = None,
        reward: str = "dense",
        render_mode: str | None = None,
        render_size: tuple[int, int] = (640, 480),
        reuse_target_side: bool = False,
        episode_cache: EpisodeCache | None = None,
        render_view: str | None = None,
        image_size: tuple[int, int] | None = None,
        frame_stack: int | None = None,
        ee_crop: int | None = None,
        ee_crop_scale: int | None = None,
        image_supersample: int | None = None,
        ee_crop_supersample: int | None = None,
    ) -> None:
        self.task = task = CaptureTask(
            scenario,
            observation_source=observation_source,
            reward=reward,
            image_size=image_size,
            frame_stack=frame_stack,
            ee_crop=ee_crop,
            ee_crop_scale=ee_crop_scale,
            image_supersample=image_supersample,
            ee_crop_supersample=ee_crop_supersample,
        )  # checks ``observation_source``, ``reward``, ``image_size`` and the pixel options
        rendered = task.scenario.camera.mode == "rendered"
        views = ("scene", "camera") if rendered else ("scene",)
        self.render_view = (
            ("camera" if rendered else "scene") if render_view is None else render_view
        )
        if self.render_view not in views:
            raise ValueError(
                f"render_view must be one of {views} for scenario {task.scenario.name!r} "
                f"(camera.mode {task.scenario.camera.mode!r}); got {render_view!r}"
            )
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        _check_display(render_mode)
        self.render_mode = render_mode
        self.render_size = _check_render_size(render_size)
        self.reuse_target_side = bool(reuse_target_side)
        self.episode_cache = DEFAULT_EPISODE_CACHE if episode_cache is None else episode_cache
        self.action_space = task.single_action_space
        self.observation_space = task.single_observation_space
        self.camera_model = task.camera.model
        self.rendered = rendered
        # The episode engine of one row (built at the first reset: it opens pybullet worlds)
        self._engine: EpisodeEngine | None = None
        self._closed = False
        self._key: EpisodeKey | None = None  # (scenario, seed) of a seeded reset
        self._time = 0.0
        self._episode_over = True

    # -- privileged API (oracle and tests only): PrivilegedView's, over these hooks ----------
    def _view_episode(self) -> RecordedEpisode | None:
        return None if self._engine is None else self._engine.episodes[0]

    def _view_step(self) -> int:
        return 0 if self._engine is None else int(self._engine.steps[0])

    def _view_time(self) -> float:
        return self._time

    def _view_bound(self, episode: RecordedEpisode) -> PhysicalLimit:
        """Computed once per episode, lazily; kept in `episode_cache` by (scenario, seed) after
        a seeded reset."""
        return self.episode_cache.bound_of(self._key, episode.plan, self.description)

    @property
    def episode_key(self) -> EpisodeKey | None:
        """(scenario, seed) of this episode, or None after an unseeded reset."""
        return self._key

    @property
    def engine(self) -> EpisodeEngine:
        """The episode engine of this env's one row (privileged: tests and benchmarks reach the
        target side, its camera and estimator through it); built when first asked for, it opens
        the env's pybullet worlds (`close` closes them)."""
        if self._engine is None:
            task = self.task
            sides = target_sides(
                task,
                1,
                self.episode_cache,
                recorded=self.reuse_target_side,
                full_horizon=True,  # the whole episode recorded at reset (see the docstring)
            )
            arm = ArmSide(task.features, task.description.arm, render_mode=self.render_mode)
            self._engine = EpisodeEngine(task, 1, sides, arm)
        return self._engine

    @property
    def joint_angles(self) -> NDArray[np.float64]:
        """Current joint angles, rad, (3,)."""
        if self._engine is None:
            return np.zeros(3)
        return self._engine.state.theta[0].copy()

    # -- gymnasium API --------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Observation, dict[str, Any]]:
        super().reset(seed=seed)
        self._closed = False
        engine = self.engine
        draw = EpisodeDraw(None if seed is None else int(seed), self.np_random)
        self._key = draw.key(self.scenario)
        info = scalar_info(engine.begin(_ROW, engine.prepare([draw])))
        self._time = 0.0
        episode = engine.episodes[0]
        assert episode is not None
        engine.arm.world.reset(self.description.arm.home, episode.position[0], episode.rotation[0])
        self._traces: dict[str, list[NDArray]] = {
            "target": [episode.position[0]],
            "end_effector": [engine.state.x_e[0].copy()],
        }
        self._episode_over = False
        return self._observe(), info

    def step(self, action: NDArray) -> tuple[Observation, float, bool, bool, dict[str, Any]]:
        if self._closed:
            raise RuntimeError("CaptureEnv.step() called after close(); the env is closed")
        engine = self._engine
        if engine is None or engine.episodes[0] is None:
            raise RuntimeError("CaptureEnv.step() called before reset(); call env.reset() first")
        if self._episode_over:
            raise RuntimeError("the episode has ended; call env.reset() before step()")
        a = check_actions(action, (3,), "action")
        out = engine.step(_ALL, a[None])
        terminated, truncated = bool(out.terminated[0]), bool(out.truncated[0])
        info = scalar_info(out.info)
        self._time = info["time"]
        self._episode_over = terminated or truncated
        if self._episode_over:
            info["physical_limit_time"] = self.physical_limit().time
        if self.render_mode is not None:  # the target never collides: only images show it
            k = int(engine.steps[0])
            episode = engine.episodes[0]
            assert episode is not None
            world = engine.arm.world
            world.set_joint_positions(engine.state.theta[0].tolist())
            world.set_target_pose(episode.position[k], episode.rotation[k])
            self._traces["target"].append(episode.position[k])
            self._traces["end_effector"].append(engine.state.x_e[0].copy())
        return self._observe(), out.reward.item(0), terminated, truncated, info

    def render(self) -> NDArray[np.uint8] | None:
        if self.render_mode is None or self._engine is None:
            return None
        width, height = self.render_size
        if self.render_view == "camera":
            return self._camera_view() if self.render_mode == "rgb_array" else None
        traces = {k: np.array(v) for k, v in self._traces.items()}
        image = self._engine.arm.world.render(width, height, traces=traces)
        return image if self.render_mode == "rgb_array" else None

    def _camera_view(self) -> NDArray[np.uint8]:
        """The rendered camera's image of this step with its detections and the estimate."""
        sides = None if self._engine is None else self._engine.sides
        side = None if not isinstance(sides, RenderedSides) else sides.sides[0]
        if side is None or sides.camera is None:  # type: ignore[union-attr]
            raise RuntimeError("call reset() before render()")
        episode, k = side.episode, self._view_step()
        state = side.camera_episode
        assert isinstance(state, SceneEpisode)  # a rendered side is live
        return sides.camera.view(  # type: ignore[union-attr]
            self.joint_angles,
            episode.position[k],
            episode.rotation[k],
            self.render_size,
            state.last_detections,
            episode.estimate_position[k],
            sides.camera.true_model(state),  # type: ignore[union-attr]
        )

    def close(self) -> None:
        """Disconnect the pybullet worlds; safe twice. ``step()`` then raises; ``reset()`` opens
        new worlds and the env can be used again."""
        self._closed = True
        if self._engine is not None:
            self._engine.close()
            self._engine = None

    def _observe(self) -> Observation:
        """The observation of the current step: the estimate's vector, or with pixels the image
        of the arm and of the true target, and the state."""
        assert self._engine is not None
        obs = self._engine.observe()
        if isinstance(obs, dict):
            return {key: value[0] for key, value in obs.items()}
        return obs[0]
