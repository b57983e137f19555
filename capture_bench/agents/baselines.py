"""Classic analytic baselines to compare with the paper's incremental IK controller.

All of them see only the observation and the environment's public
[`TaskDescription`][capture_bench.agents.baselines.TaskDescription], and
answer in the shared action space ``Box(-1, 1, (3,))`` (``dTheta = a * theta_dot_max * t_s``), so
they are held to the same joint-rate limits as every other agent.

* `PurePursuit` — aims at the current estimate X^_T, no look-ahead.
* `Intercept` — aims at the predicted interception point, re-planned every step.
* `JointIntercept` — the joints straight to the earliest pose that meets the predicted
  target, the physical limit's test on the estimate, re-planned every step.
* `DampedLeastSquares` — resolved-rate control with feed-forward and a proportional term.
* `JointInterceptDLS` — `JointIntercept` far from the target, `DampedLeastSquares` near it.
* `RandomAgent` — uniform actions from its own seeded generator.
* `Hold` — never moves.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from capture_bench.agents.base import AnalyticController, safe_action
from capture_bench.agents.incremental_ik import incremental_steps, lambda_max_of, resolve_direction
from capture_bench.sim.kinematics import forward_kinematics, jacobian
from capture_bench.task.observation import OBSERVATION_SIZE, TaskDescription
from capture_bench.task.physical_limit import first_feasible

FloatArray = NDArray[np.float64]


class PurePursuit(AnalyticController):
    """Pure pursuit: move straight at the target's *current* estimated position, as fast as the
    joint-rate limits allow.

    Classic pursuit guidance (the "pursuit curve" of Bouguer, 1732; see N. A. Shneydor, *Missile
    Guidance and Pursuit*, Horwood, 1998): the pursuer's velocity always points at the target's
    present position. It is eqs. 14-19 of Dong & Zhu (2016) without the eq. 13 look-ahead, i.e. with
    X_T' = X^_T, and with the same step cap.

    Args:
        description: the environment's public description.
        cap: step cap lambda = min(lambda_max, ||X^_T - X_E|| / t_s) (default on).
    """

    def __init__(self, description: TaskDescription, cap: bool = True) -> None:
        super().__init__(description)
        self.cap = cap

    def act_batch(self, observations: NDArray) -> NDArray[np.float32]:
        """Actions for N observations, (N, 16) -> (N, 3), float32, in [-1, 1]."""
        obs = self.decode(observations)
        still = np.zeros(obs.target_position.shape)
        step = incremental_steps(
            obs.joint_angles, obs.target_position, still, self.description, cap=self.cap
        )
        return safe_action(self.description.increment_to_action(step.increment))


REFINE_POINTS = 64
#: `JointInterceptDLS`'s switch: the DLS step within this distance of X^_T, m.
JOINT_INTERCEPT_NEAR = 0.03


def interception_times(
    theta: NDArray,
    target_position: NDArray,
    target_velocity: NDArray,
    description: TaskDescription,
    horizon: float = 10.0,
    samples: int = 400,
    refinements: int = 2,
) -> FloatArray:
    """Earliest tau > 0 at which the end-effector, moving straight at its top speed, meets the
    target's predicted straight-line path, for N episodes at once.

    The target is predicted at ``P(tau) = X^_T + Xdot^_T tau``. Along the direction
    ``n(tau) = (P(tau) - X_E)/||P(tau) - X_E||`` the end-effector's top speed at the current pose
    is ``lambda_max(n)`` (eq. 18 with u = J^-1 n, the Jacobian frozen at the current Theta).
    Interception is the smallest tau with ``lambda_max(n(tau)) tau >= ||P(tau) - X_E||``: found on
    a uniform grid over (0, horizon], then the bracketing interval is searched again on a finer
    grid ``refinements`` times (64-fold each). Rows do not mix.

    Args:
        theta: joint angles, rad, shape (N, 3).
        target_position: X^_T, global frame, m, shape (N, 3).
        target_velocity: Xdot^_T, global frame, m/s, shape (N, 3).
        description: public description (rate limits).
        horizon: longest look-ahead, s.
        samples: grid points over (0, horizon].
        refinements: finer-grid passes after the first grid.

    Returns:
        tau in seconds, shape (N,); NaN where the path is not met within the horizon.
    """
    theta = np.asarray(theta, dtype=float)
    x_e = forward_kinematics(theta)[:, None]  # (N, 1, 3)
    p0 = np.asarray(target_position, dtype=float)[:, None]
    v = np.asarray(target_velocity, dtype=float)[:, None]
    rates = description.arm.joint_rate_limits

    def feasible(rows: NDArray, tau: NDArray) -> NDArray[np.bool_]:
        """Whether the end-effector can be at P(tau) by tau, for taus (M, S) of ``rows``."""
        offset = p0[rows] + tau[..., None] * v[rows] - x_e[rows]
        distance = np.linalg.norm(offset, axis=-1)
        n = offset / np.maximum(distance, 1e-12)[..., None]
        u, _ = resolve_direction(theta[rows], n)
        return lambda_max_of(u, rates) * tau - distance >= 0.0

    out = np.full(theta.shape[0], np.nan)
    taus = np.linspace(horizon / samples, horizon, samples)
    everyone = np.arange(theta.shape[0])
    ok = feasible(everyone, np.broadcast_to(taus, (everyone.size, samples)))
    rows = everyone[ok.any(axis=1)]
    if rows.size == 0:
        return out
    k = np.argmax(ok[rows], axis=1)
    lo = np.where(k == 0, 0.0, taus[np.maximum(k - 1, 0)])
    hi = taus[k]
    for _ in range(refinements):  # each pass narrows the bracket REFINE_POINTS-fold
        fine = np.linspace(lo, hi, REFINE_POINTS + 1, axis=1)[:, 1:]  # the last is hi: feasible
        j = np.argmax(feasible(rows, fine), axis=1)
        pick = np.arange(rows.size)
        lo, hi = np.where(j == 0, lo, fine[pick, np.maximum(j - 1, 0)]), fine[pick, j]
    out[rows] = hi
    return out


class Intercept(AnalyticController):
    """Aim at the predicted interception point, re-planned every control period.

    Classic interception (collision-course / constant-bearing) guidance: rather than chase the
    target, head for the point where the target will be when the pursuer can get there, assuming it
    keeps its estimated velocity (Shneydor 1998, parallel navigation / collision course). The
    interception time comes from `interception_times`; the end-effector then moves at
    lambda_max (eq. 18) toward ``P(max(tau, t_s))`` with the same step cap as the paper's
    controller. With no solution within the horizon it falls back to pure pursuit.

    Args:
        description: the environment's public description.
        horizon: longest look-ahead, s.
        cap: step cap (default on).
    """

    def __init__(self, description: TaskDescription, horizon: float = 10.0, cap: bool = True):
        super().__init__(description)
        self.horizon = horizon
        self.cap = cap
        #: the last call's interception times, s, one per observation (NaN: none)
        self.last_tau: FloatArray | None = None

    def act_batch(self, observations: NDArray) -> NDArray[np.float32]:
        """Actions for N observations, (N, 16) -> (N, 3), float32, in [-1, 1]."""
        obs = self.decode(observations)
        tau = interception_times(
            obs.joint_angles,
            obs.target_position,
            obs.target_velocity,
            self.description,
            horizon=self.horizon,
        )
        self.last_tau = tau
        # no interception (NaN): pure pursuit; else lead by max(tau, t_s)
        lead = np.where(np.isnan(tau), 0.0, np.maximum(tau, self.description.control_period))
        aim = obs.target_position + obs.target_velocity * lead[:, None]
        still = np.zeros(aim.shape)
        step = incremental_steps(obs.joint_angles, aim, still, self.description, cap=self.cap)
        return safe_action(self.description.increment_to_action(step.increment))

    def reset(self) -> None:
        """Forget the last interception time."""
        super().reset()
        self.last_tau = None


class JointIntercept(AnalyticController):
    """Drive the joints straight to the earliest pose that meets the predicted target.

    The physical limit's test (``capture_bench/task/physical_limit.py``) on the estimate instead
    of the truth, re-planned every control period: with the target predicted at
    ``P(tau) = X^_T + Xdot^_T tau``, ``tau`` is the first multiple of t_s within ``horizon`` at
    which ``P(tau)`` has an IK solution ``Theta*`` inside the joint limits and the box
    ``|Theta*_i - Theta_i| <= theta_dot_max_i tau`` that the rate limits let each joint reach
    (within ``|epsilon|``: `first_feasible`). Where
    Cartesian controllers move the end-effector along a line at the speed the slowest joint allows
    (eq. 18), every joint here runs at up to its own rate.

    * Capped (``cap=True``): ``a = clip((Theta* - Theta) / (theta_dot_max t_s), -1, 1)``, each
      joint at full rate until its last step lands on ``Theta*``: it arrives.
    * Uncapped (``cap=False``): the same direction scaled so that the joint furthest from
      ``Theta*`` in steps runs at full rate every step, sweeping through the pose.

    With no such pose within the horizon it takes the paper's incremental IK step (eqs. 13-19,
    with the same cap). Rows do not mix.

    Args:
        description: the environment's public description.
        horizon: longest look-ahead, s.
        cap: arrive (default) or sweep through at full rate.
    """

    def __init__(self, description: TaskDescription, horizon: float = 6.0, cap: bool = True):
        super().__init__(description)
        self.horizon = horizon
        self.cap = cap

    def act_batch(self, observations: NDArray) -> NDArray[np.float32]:
        """Actions for N observations, (N, 16) -> (N, 3), float32, in [-1, 1]."""
        obs = self.decode(observations)
        arm, t_s = self.description.arm, self.description.control_period
        theta = np.asarray(obs.joint_angles, dtype=float)
        n = theta.shape[0]
        taus = t_s * np.arange(1, int(round(self.horizon / t_s)) + 1)  # (K,)
        k = taus.size
        predicted = (
            obs.target_position[:, None] + taus[None, :, None] * obs.target_velocity[:, None]
        )
        first, theta_star = first_feasible(
            predicted.reshape(n * k, 3),
            np.tile(taus, n),
            np.arange(n + 1) * k,  # row i's taus are one segment
            np.repeat(theta, k, axis=0),
            arm.joint_rate_limits,
            arm.joint_lower,
            arm.joint_upper,
            self.description.capture_tolerance,
        )
        action = (theta_star - theta) / (arm.joint_rate_limits * t_s)
        if not self.cap:
            steps = np.max(np.abs(action), axis=1, keepdims=True)
            action = np.divide(action, steps, out=np.zeros_like(action), where=steps > 0)
        none = first >= n * k
        if np.any(none):
            step = incremental_steps(
                theta[none],
                obs.target_position[none],
                obs.target_velocity[none],
                self.description,
                cap=self.cap,
            )
            action[none] = self.description.increment_to_action(step.increment)
        return safe_action(action)


class DampedLeastSquares(AnalyticController):
    """Damped-least-squares resolved-rate control with feed-forward and a proportional term.

    ``Thetadot = J^T (J J^T + mu^2 I)^-1 (Xdot^_T + K (X^_T - X_E))`` — the singularity-robust
    inverse of Wampler (1986, IEEE Trans. SMC 16(1)) and Nakamura & Hanafusa (1986, ASME J. Dyn.
    Syst. Meas. Control 108(3)), in the closed-loop inverse-kinematics form with a velocity
    feed-forward (Siciliano 1990, J. Intell. Robot. Syst. 3). The joint rate is then scaled
    *uniformly* by ``min(1, min_i theta_dot_max_i / |Thetadot_i|)``, which keeps its direction
    (clipping each joint separately would bend the path). ``dTheta = Thetadot t_s``.

    Args:
        description: the environment's public description.
        gain: proportional gain K, 1/s; default ``0.5 / t_s`` (halves the error per step, stable
            for K t_s < 2).
        damping: mu, m.
    """

    def __init__(
        self, description: TaskDescription, gain: float | None = None, damping: float = 0.02
    ) -> None:
        super().__init__(description)
        self.gain = 0.5 / description.control_period if gain is None else float(gain)
        self.damping = damping

    def act_batch(self, observations: NDArray) -> NDArray[np.float32]:
        """Actions for N observations, (N, 16) -> (N, 3), float32, in [-1, 1]."""
        obs = self.decode(observations)
        theta = obs.joint_angles
        jac = jacobian(theta)  # (N, 3, 3)
        jac_t = np.swapaxes(jac, 1, 2)
        x_e = forward_kinematics(theta)
        desired = obs.target_velocity + self.gain * (obs.target_position - x_e)  # m/s
        lhs = jac @ jac_t + self.damping**2 * np.eye(3)
        rate = (jac_t @ np.linalg.solve(lhs, desired[..., None]))[..., 0]  # rad/s
        limits = self.description.arm.joint_rate_limits
        peak = np.max(np.abs(rate) / limits, axis=1)
        rate = np.where((peak > 1.0)[:, None], rate / peak[:, None], rate)  # keeps the direction
        increment = rate * self.description.control_period  # rad
        return safe_action(self.description.increment_to_action(increment))


class JointInterceptDLS(AnalyticController):
    """`JointIntercept` while the estimate is far, `DampedLeastSquares` near it.

    Where ``||X^_T - X_E|| > near`` every joint runs at up to its own rate to the earliest pose
    that meets the predicted target (`JointIntercept`, capped: the fast approach); within
    ``near`` the damped-least-squares step matches the target's estimated velocity and closes the
    remaining distance, halving it per step (`DampedLeastSquares`): the landing slows into the
    capture envelope and tracks through its hold. The switch reads the observation alone, so the
    controller is a function of it (no state kept between calls), as a residual base or an
    imitation's teacher needs.

    Args:
        description: the environment's public description.
        near: the distance from the end-effector to X^_T below which the DLS step acts, m.
    """

    def __init__(self, description: TaskDescription, near: float = JOINT_INTERCEPT_NEAR) -> None:
        super().__init__(description)
        if not near > 0.0:
            raise ValueError(f"near must be > 0 m, got {near}")
        self.near = float(near)
        self.far_controller = JointIntercept(description)
        self.near_controller = DampedLeastSquares(description)

    def act_batch(self, observations: NDArray) -> NDArray[np.float32]:
        """Actions for N observations, (N, 16) -> (N, 3), float32, in [-1, 1]."""
        rows = np.asarray(observations).reshape(-1, OBSERVATION_SIZE)
        obs = self.decode(rows)
        x_e = forward_kinematics(obs.joint_angles)
        distance = np.linalg.norm(obs.target_position - x_e, axis=1)
        action = self.near_controller.act_batch(rows)
        far = distance > self.near
        if np.any(far):
            action[far] = self.far_controller.act_batch(rows[far])
        return action


class RandomAgent(AnalyticController):
    """Uniform random actions in [-1, 1]^3: the floor every controller should beat.

    Draws from its own ``numpy.random.Generator`` seeded at construction (no global RNG); the
    stream continues across episodes, so the same seed gives the same sequence of episodes.

    Args:
        description: the environment's public description (unused beyond the protocol).
        seed: seed of the generator.
    """

    acquires = False

    def __init__(self, description: TaskDescription, seed: int = 0) -> None:
        super().__init__(description)
        self.rng = np.random.default_rng(seed)

    def act(self, observation: NDArray) -> NDArray[np.float32]:
        """A uniform random action, shape (3,), float32."""
        self.decode(observation)  # validates the shape
        return self.rng.uniform(-1.0, 1.0, 3).astype(np.float32)


class Hold(AnalyticController):
    """Zero action: the arm stays at home. Captures only a target that comes to the end-effector."""

    acquires = False

    def act_batch(self, observations: NDArray) -> NDArray[np.float32]:
        """The zero action for each of N observations, shape (N, 3), float32."""
        obs = self.decode(observations)  # validates the shape
        return np.zeros(obs.joint_angles.shape, dtype=np.float32)


__all__ = [
    "DampedLeastSquares",
    "Hold",
    "Intercept",
    "JointIntercept",
    "PurePursuit",
    "RandomAgent",
    "interception_times",
]
