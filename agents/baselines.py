"""Classic analytic baselines to compare with the paper's incremental IK controller.

All of them see only the observation and the environment's public :class:`TaskDescription`, and
answer in the shared action space ``Box(-1, 1, (3,))`` (``dTheta = a * theta_dot_max * t_s``), so
they are held to the same joint-rate limits as every other agent.

* :class:`PurePursuit` — aims at the current estimate X^_T, no look-ahead.
* :class:`Intercept` — aims at the predicted interception point, re-planned every step.
* :class:`DampedLeastSquares` — resolved-rate control with feed-forward and a proportional term.
* :class:`RandomAgent` — uniform actions from its own seeded generator.
* :class:`Hold` — never moves.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from agents.base import AnalyticController, safe_action
from agents.incremental_ik import incremental_step, lambda_max_of, resolve_direction
from capture_bench.sim.kinematics import forward_kinematics, jacobian
from capture_bench.task.observation import TaskDescription


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

    def act(self, observation: NDArray) -> NDArray[np.float32]:
        """Action for one observation, shape (3,), float32, in [-1, 1]."""
        obs = self.decode(observation)
        step = incremental_step(
            obs.joint_angles, obs.target_position, np.zeros(3), self.description, cap=self.cap
        )
        return safe_action(self.description.increment_to_action(step.increment))


REFINE_POINTS = 64


def interception_time(
    theta: NDArray,
    target_position: NDArray,
    target_velocity: NDArray,
    description: TaskDescription,
    horizon: float = 10.0,
    samples: int = 400,
    refinements: int = 2,
) -> float | None:
    """Earliest tau > 0 at which the end-effector, moving straight at its top speed, meets the
    target's predicted straight-line path.

    The target is predicted at ``P(tau) = X^_T + Xdot^_T tau``. Along the direction
    ``n(tau) = (P(tau) - X_E)/||P(tau) - X_E||`` the end-effector's top speed at the current pose
    is ``lambda_max(n)`` (eq. 18 with u = J^-1 n, the Jacobian frozen at the current Theta).
    Interception is the smallest tau with ``lambda_max(n(tau)) tau >= ||P(tau) - X_E||``: found on
    a uniform grid over (0, horizon], then the bracketing interval is searched again on a finer
    grid ``refinements`` times (64-fold each: 6 microseconds at the defaults).

    Args:
        theta: joint angles, rad, shape (3,).
        target_position: X^_T, global frame, m, shape (3,).
        target_velocity: Xdot^_T, global frame, m/s, shape (3,).
        description: public description (rate limits).
        horizon: longest look-ahead, s.
        samples: grid points over (0, horizon].
        refinements: finer-grid passes after the first grid.

    Returns:
        tau in seconds, or ``None`` when the path is not met within the horizon.
    """
    theta = np.asarray(theta, dtype=float)
    x_e = forward_kinematics(theta)
    p0 = np.asarray(target_position, dtype=float)
    v = np.asarray(target_velocity, dtype=float)
    rates = description.arm.joint_rate_limits

    def slack(tau: NDArray) -> NDArray:
        offset = p0 + np.outer(tau, v) - x_e
        distance = np.linalg.norm(offset, axis=1)
        n = offset / np.maximum(distance, 1e-12)[:, None]
        u, _ = resolve_direction(theta, n)
        return lambda_max_of(u, rates) * tau - distance

    taus = np.linspace(horizon / samples, horizon, samples)
    feasible = slack(taus) >= 0.0
    if not np.any(feasible):
        return None
    k = int(np.argmax(feasible))
    lo, hi = (0.0 if k == 0 else float(taus[k - 1])), float(taus[k])
    for _ in range(refinements):  # each pass narrows the bracket REFINE_POINTS-fold
        fine = np.linspace(lo, hi, REFINE_POINTS + 1)[1:]  # the last point is hi: feasible
        j = int(np.argmax(slack(fine) >= 0.0))
        lo, hi = (lo if j == 0 else float(fine[j - 1])), float(fine[j])
    return hi


class Intercept(AnalyticController):
    """Aim at the predicted interception point, re-planned every control period.

    Classic interception (collision-course / constant-bearing) guidance: rather than chase the
    target, head for the point where the target will be when the pursuer can get there, assuming it
    keeps its estimated velocity (Shneydor 1998, parallel navigation / collision course). The
    interception time comes from :func:`interception_time`; the end-effector then moves at
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
        self.last_tau: float | None = None

    def act(self, observation: NDArray) -> NDArray[np.float32]:
        """Action for one observation, shape (3,), float32, in [-1, 1]."""
        obs = self.decode(observation)
        tau = interception_time(
            obs.joint_angles,
            obs.target_position,
            obs.target_velocity,
            self.description,
            horizon=self.horizon,
        )
        self.last_tau = tau
        if tau is None:  # no interception: pure pursuit
            aim = obs.target_position
        else:
            lead = max(tau, self.description.control_period)  # s
            aim = obs.target_position + obs.target_velocity * lead
        step = incremental_step(obs.joint_angles, aim, np.zeros(3), self.description, cap=self.cap)
        return safe_action(self.description.increment_to_action(step.increment))

    def reset(self) -> None:
        """Forget the last interception time."""
        self.last_tau = None


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

    def act(self, observation: NDArray) -> NDArray[np.float32]:
        """Action for one observation, shape (3,), float32, in [-1, 1]."""
        obs = self.decode(observation)
        theta = obs.joint_angles
        jac = jacobian(theta)
        x_e = forward_kinematics(theta)
        desired = obs.target_velocity + self.gain * (obs.target_position - x_e)  # m/s
        lhs = jac @ jac.T + self.damping**2 * np.eye(3)
        rate = jac.T @ np.linalg.solve(lhs, desired)  # rad/s
        limits = self.description.arm.joint_rate_limits
        peak = float(np.max(np.abs(rate) / limits))
        if peak > 1.0:
            rate = rate / peak  # uniform scaling keeps the direction
        increment = rate * self.description.control_period  # rad
        return safe_action(self.description.increment_to_action(increment))


class RandomAgent(AnalyticController):
    """Uniform random actions in [-1, 1]^3: the floor every controller should beat.

    Draws from its own ``numpy.random.Generator`` seeded at construction (no global RNG); the
    stream continues across episodes, so the same seed gives the same sequence of episodes.

    Args:
        description: the environment's public description (unused beyond the protocol).
        seed: seed of the generator.
    """

    def __init__(self, description: TaskDescription, seed: int = 0) -> None:
        super().__init__(description)
        self.rng = np.random.default_rng(seed)

    def act(self, observation: NDArray) -> NDArray[np.float32]:
        """A uniform random action, shape (3,), float32."""
        self.decode(observation)  # validates the shape
        return self.rng.uniform(-1.0, 1.0, 3).astype(np.float32)


class Hold(AnalyticController):
    """Zero action: the arm stays at home. Captures only a target that comes to the end-effector."""

    def act(self, observation: NDArray) -> NDArray[np.float32]:
        """The zero action, shape (3,), float32."""
        self.decode(observation)  # validates the shape
        return np.zeros(3, dtype=np.float32)


__all__ = [
    "DampedLeastSquares",
    "Hold",
    "Intercept",
    "PurePursuit",
    "RandomAgent",
    "interception_time",
]
