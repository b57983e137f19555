"""TargetEstimator: each row step for step the numbers of the reference scalar estimator
(``references.scalar_estimator``, filterpy's EKF) of that episode alone, and the same bit for bit
whatever the other rows (any batch size, the one-row path, rows moved by snapshot/restore)."""

from __future__ import annotations

import numpy as np
import pytest
from references.scalar_estimator import TargetEstimator as ScalarEstimator

from capture_bench.sensing.camera import Camera, CameraModel, Frame
from capture_bench.sensing.estimator import (
    BLOCK_ORDER,
    DIVERGENCE_FRAMES,
    STATUSES,
    Estimates,
    TargetEstimator,
)
from capture_bench.sensing.photogrammetry import pose_projection
from capture_bench.sim import kinematics
from capture_bench.sim.target_motion import FEATURE_POINTS, sample_trajectory
from capture_bench.task.scenarios import load_scenario

# TargetEstimator and the reference run the same equations by different routes: the reference
# is filterpy's EKF (K = P H' inv(S), one episode at a time), TargetEstimator solves
# S^-1 [y, H P] with np.linalg.solve on stacked rows. Their floats agree to rounding, not bit
# for bit. A re-initialised EKF's velocity amplifies that rounding (2.4e-10 rad/s on an angular
# rate of 0.011, 18 steps after a restart, seen here), so the states (m, m/s, rad, rad/s) get
# an absolute 1e-9 floor; covariances keep 1e-12.
RTOL, ATOL, STATE_ATOL = 1e-9, 1e-12, 1e-9
ESTIMATE_FIELDS = ("position", "velocity", "covariance", "valid", "status")


class Sequences:
    """Per-env images (T, n, N, 2) (NaN: no frame) and periods (T, n) from a scenario."""

    def __init__(self, name: str, n: int, steps: int, seed: int, **target: object) -> None:
        sc = load_scenario(name)
        if target:
            sc = sc.replace(target=target)
        cam = sc.camera
        self.model = CameraModel.looking_at(
            cam.position,
            cam.look_at,
            focal_length=cam.focal_length,
            pixel_pitch=cam.pixel_pitch,
            resolution=cam.resolution,
        )
        self.features = FEATURE_POINTS[sc.target.feature_points]
        self.noise_px = cam.noise_px
        self.sigmas = (sc.estimator.sigma_acceleration, sc.estimator.sigma_angular_acceleration)
        anchor = kinematics.forward_kinematics(kinematics.ArmSpec().home)
        period, jitter = sc.control.period, sc.control.period_jitter
        self.images = np.full((steps, n, self.features.shape[0], 2), np.nan)
        self.dts = np.full((steps, n), period)
        for i in range(n):
            rng = np.random.default_rng([seed, i])
            while True:  # a target that stays in view (like the env's placement)
                traj = sample_trajectory(sc.target, rng, anchor, steps * period)
                if all(
                    self.model.visible(
                        self.model.to_camera(traj.feature_points(t, self.features)), margin=0.1
                    ).all()
                    for t in (0.0, 0.5 * steps * period, 1.5 * steps * period)
                ):
                    break
            sensor = Camera(self.model, cam.noise_px, cam.dropout, cam.latency_frames)
            state = sensor.reset()
            t = 0.0
            for k in range(steps):
                if jitter:
                    self.dts[k, i] = period * (1.0 + jitter * rng.uniform(-1.0, 1.0))
                t += self.dts[k, i]
                frame = sensor.capture(state, traj.feature_points(t, self.features), rng)
                if frame is not None:
                    self.images[k, i] = frame.image_points

    def settings(self, **more: object) -> dict[str, object]:
        """The scenario's estimator settings, and ``more``."""
        return dict(
            noise_px=self.noise_px,
            sigma_acceleration=self.sigmas[0],
            sigma_angular_acceleration=self.sigmas[1],
            **more,
        )

    def estimators(self, n: int, **more: object) -> tuple[TargetEstimator, list[ScalarEstimator]]:
        """An n-row estimator and n reference scalar estimators with the same settings."""
        kwargs = self.settings(**more)
        rows = TargetEstimator(n, self.model, self.features, **kwargs)  # type: ignore[arg-type]
        singles = [ScalarEstimator(self.model, self.features, **kwargs) for _ in range(n)]  # type: ignore[arg-type]
        return rows, singles


def step_both(
    batch: TargetEstimator,
    singles: list[ScalarEstimator],
    images: np.ndarray,
    dts: np.ndarray,
    active: np.ndarray | None = None,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[Estimates, list[str | None]]:
    """One step of the n-row estimator and of the active reference estimators; checks each
    active row agrees with its reference.

    Returns the estimates and the reference estimators' statuses (None where inactive).
    """
    out = batch.update(images, dts, active, truth)
    assert out.position.shape == out.velocity.shape == (len(singles), 3)
    assert out.covariance.shape == (len(singles), 6, 6) and out.status.dtype == np.int8
    statuses: list[str | None] = []
    for i, est in enumerate(singles):
        if active is not None and not active[i]:
            statuses.append(None)
            continue
        image = images[i]
        frame = Frame(image.copy()) if np.isfinite(image).all(axis=1).any() else None
        true_pv = (np.zeros(3), np.zeros(3)) if truth is None else (truth[0][i], truth[1][i])
        ref = est.update(frame, float(dts[i]), *true_pv)
        statuses.append(ref.status)
        where = f"env {i}"
        assert STATUSES[out.status[i]] == ref.status, where
        assert bool(out.valid[i]) == ref.valid, where
        assert batch.reinitialisations[i] == est.reinitialisations, where
        if ref.valid and ref.covariance is None:  # photogrammetry, truth: no covariance
            np.testing.assert_allclose(
                out.position[i], ref.position, RTOL, STATE_ATOL, err_msg=where
            )
            np.testing.assert_allclose(
                out.velocity[i], ref.velocity, RTOL, STATE_ATOL, err_msg=where
            )
            assert np.isnan(out.covariance[i]).all(), where
        elif ref.valid:
            np.testing.assert_allclose(
                out.position[i], ref.position, RTOL, STATE_ATOL, err_msg=where
            )
            np.testing.assert_allclose(
                out.velocity[i], ref.velocity, RTOL, STATE_ATOL, err_msg=where
            )
            assert ref.covariance is not None
            np.testing.assert_allclose(out.covariance[i], ref.covariance, RTOL, ATOL, err_msg=where)
            # The whole filter state, in the paper's order (angles wrapped alike).
            np.testing.assert_allclose(batch.state[i], est.ekf.x, RTOL, STATE_ATOL, err_msg=where)
            np.testing.assert_allclose(batch.covariance[i], est.ekf.P, RTOL, ATOL, err_msg=where)
        else:
            assert np.isnan(out.position[i]).all() and np.isnan(out.velocity[i]).all(), where
            assert np.isnan(out.covariance[i]).all(), where
    return out, statuses


def run_sequences(seq: Sequences, n: int) -> list[list[str | None]]:
    batch, singles = seq.estimators(n)
    return [step_both(batch, singles, z, dt)[1] for z, dt in zip(seq.images, seq.dts)]


@pytest.mark.parametrize(
    "name, target",
    [
        ("paper", {}),  # 1 px noise, slow drift, some tumbling
        ("paper", {"motion": "circular"}),  # 1 px noise on a circular path
        ("noisy", {}),  # 2 px, 20% drop-outs, one frame of latency
        ("jitter", {}),  # the period varies +-60% step to step
    ],
)
def test_rows_equal_the_reference_estimators_on_scenarios(name, target):
    n, steps = 5, 60
    seq = Sequences(name, n, steps, seed=7, **target)
    statuses = run_sequences(seq, n)
    seen = {s for row in statuses for s in row}
    assert "ok" in seen and "diverged" not in seen
    if name == "noisy":  # latency: no frame at first; drop-outs: predict-only steps
        assert statuses[0] == ["initialising"] * n and "predicting" in seen
    if name == "jitter":
        assert np.ptp(seq.dts) > 0.03


@pytest.mark.parametrize("rule", ["update", "predict"])
def test_frames_missing_some_points_follow_the_same_rule_as_the_reference(rule):
    """Rendered-camera frames: markers not found (NaN rows), in runs of steps, one to three at a
    time, before and after the filters start; every row equals its reference estimator under
    either rule, and a frame missing a point never initialises a filter."""
    n, steps = 5, 60
    seq = Sequences("paper", n, steps, seed=11)
    rng = np.random.default_rng(5)
    for i in range(n):
        for _ in range(6):
            start, length = rng.integers(0, steps), rng.integers(1, 8)
            hidden = rng.choice(4, size=rng.integers(1, 4), replace=False)
            seq.images[start : start + length, i, hidden] = np.nan
    seq.images[:4, 0, 1] = np.nan  # env 0 starts with a marker hidden: it must wait
    batch, singles = seq.estimators(n, partial_frames=rule)
    statuses = [step_both(batch, singles, z, dt)[1] for z, dt in zip(seq.images, seq.dts)]
    assert [row[0] for row in statuses[:4]] == ["initialising"] * 4
    partial = np.isnan(seq.images).any(axis=(2, 3)) & ~np.isnan(seq.images).all(axis=(2, 3))
    after_start = [statuses[k][i] for k, i in zip(*np.nonzero(partial)) if k > 5]
    assert after_start and set(after_start) == ({"ok"} if rule == "update" else {"predicting"})


def test_envs_that_start_without_frames_initialise_later():
    n, steps = 4, 40
    seq = Sequences("paper", n, steps, seed=3)
    for i, start in enumerate((0, 3, 11, 25)):
        seq.images[:start, i] = np.nan
    seq.images[5, 1, 2, 0] = np.inf  # one non-finite value: that point not seen
    statuses = run_sequences(seq, n)
    for i, start in enumerate((0, 3, 11, 25)):
        column = [row[i] for row in statuses]
        assert column[:start] == ["initialising"] * start
        assert column[start] == "ok"
    assert statuses[5][1] == "ok"  # updated with the three points seen


def _declare_diverged_once(est: ScalarEstimator) -> None:
    """The reference's next update declares its filter diverged and restarts it from
    photogrammetry of the frame (what TargetEstimator does where S is not positive definite);
    later updates are its own."""
    update = est.update

    def diverge(frame: Frame | None, *_: object):
        est.update = update  # type: ignore[method-assign]
        assert frame is not None
        return est._declare_diverged(np.asarray(frame.image_points, dtype=float))

    est.update = diverge  # type: ignore[method-assign]


def test_divergence_and_reinitialisation():
    """Each divergence rule of the reference estimator, in its own env, at the same step."""
    n, steps = 6, 40
    seq = Sequences("paper", n, steps, seed=11)
    batch, singles = seq.estimators(n)
    for k in range(20):
        step_both(batch, singles, seq.images[k], seq.dts[k])
    rng = np.random.default_rng(0)
    shifted = seq.images[20:].copy()
    # env 0: the target jumps (image shifted 40 px): NIS > limit until the rule trips, then
    # photogrammetry restarts the filter from the shifted frames.
    shifted[:, 0] += 40 * seq.model.pixel_pitch
    # env 1: garbage points on the sensor: rejected by the NIS rule and by photogrammetry.
    half = seq.model.half_extent
    shifted[:, 1] = rng.uniform(-0.5, 0.5, shifted[:, 1].shape) * half
    statuses = []
    for k in range(steps - 20):
        if k == 2:
            # env 2: a non-finite covariance with a frame; env 3: without a frame.
            for i in (2, 3):
                nan_p = singles[i].ekf.covariance
                nan_p[0, 0] = np.nan
                singles[i].ekf.set_state(covariance=nan_p)
                batch.P[i, 0, 0] = np.nan
            shifted[k, 3] = np.nan
            # env 4: a prediction behind the lens (y_dot toward the camera).
            fast = singles[4].ekf.state
            fast[3] = -40.0
            singles[4].ekf.set_state(state=fast)
            batch.x[4, BLOCK_ORDER.tolist().index(3)] = -40.0
            # env 5: S not positive definite. The reference has no such rule (filterpy inverts
            # S by LU and carries on): for this step it is told what the rule does, a restart
            # from photogrammetry of the frame.
            batch.P[5] = -np.eye(12)
            _declare_diverged_once(singles[5])
        statuses.append(step_both(batch, singles, shifted[k], seq.dts[20 + k])[1])
    column = [[row[i] for row in statuses] for i in range(n)]
    assert column[0][DIVERGENCE_FRAMES - 1] == "ok" and batch.reinitialisations[0] == 1
    assert "diverged" in column[1] and column[1][-1] == "diverged"
    assert batch.reinitialisations[1] == 0 and batch.diverged[1]
    assert column[2][2] == "ok" and batch.reinitialisations[2] == 1
    assert column[3][2:4] == ["diverged", "ok"] and batch.reinitialisations[3] == 1
    assert column[4][2] == "ok" and batch.reinitialisations[4] == 1
    assert column[5][2] == "ok" and batch.reinitialisations[5] == 1
    # A diverged filter that is reset is initialising again.
    batch.reset(np.arange(n) == 1)
    singles[1].reset()
    statuses = step_both(batch, singles, shifted[-1], seq.dts[-1])[1]
    assert statuses[1] == "initialising"


def test_euler_angles_wrap_like_the_reference_filter():
    """A target whose camera-frame theta_z sits at pi: the estimate crosses it and wraps."""
    seq = Sequences("paper", 1, 1, seed=0)
    n, steps = 3, 40
    batch, singles = seq.estimators(n)
    rng = np.random.default_rng(6)
    poses = [(0.0, 1.1, 0.0, 0.3, 0.2, np.pi - 1e-3), (0.05, 1.2, 0.02, -np.pi + 1e-3, 0.1, 0.5)]
    poses.append((0.0, 1.3, 0.0, 0.1, -0.2, -0.3))
    f, pitch = seq.model.focal_length, seq.model.pixel_pitch
    clean = np.array([pose_projection(np.array(p), seq.features, f)[0] for p in poses])
    signs = set()
    for _ in range(steps):
        images = (clean + rng.normal(0.0, pitch, clean.shape)).reshape(n, 4, 2)
        step_both(batch, singles, images, np.full(n, 0.05))
        signs.add((np.sign(singles[0].ekf.x[10]), np.sign(singles[1].ekf.x[6])))
    assert {s[0] for s in signs} == {1.0, -1.0} and {s[1] for s in signs} == {1.0, -1.0}
    assert np.all(np.abs(batch.state[:, 6::2]) <= np.pi)


def test_active_mask_freezes_the_other_envs():
    n, steps = 6, 50
    seq = Sequences("noisy", n, steps, seed=5)
    batch, singles = seq.estimators(n)
    rng = np.random.default_rng(1)
    for k in range(steps):
        active = rng.random(n) < 0.6
        x_before, p_before = batch.x.copy(), batch.P.copy()
        flags = (batch.initialised.copy(), batch.diverged.copy(), batch.high_nis.copy())
        step_both(batch, singles, seq.images[k], seq.dts[k], active)
        idle = ~active
        np.testing.assert_array_equal(batch.x[idle], x_before[idle])
        np.testing.assert_array_equal(batch.P[idle], p_before[idle])
        for before, after in zip(flags, (batch.initialised, batch.diverged, batch.high_nis)):
            np.testing.assert_array_equal(after[idle], before[idle])
    # The inactive envs' rows carry no estimate.
    out = batch.update(seq.images[0], seq.dts[0], np.zeros(n, dtype=bool))
    assert not out.valid.any() and np.isnan(out.position).all()


def test_reset_forgets_only_the_chosen_envs():
    n, steps = 4, 30
    seq = Sequences("paper", n, steps, seed=9)
    batch, singles = seq.estimators(n)
    statuses = []
    for k in range(steps):
        if k in (10, 20):
            which = np.array([True, False, k == 20, False])
            batch.reset(which)
            for i in np.flatnonzero(which):
                singles[i].reset()
            seq.images[k, 0] = np.nan  # env 0 has no frame right after its reset
        statuses.append(step_both(batch, singles, seq.images[k], seq.dts[k])[1])
    assert statuses[10] == ["initialising", "ok", "ok", "ok"]
    assert statuses[11][0] == "ok"
    batch.reset()
    out = batch.update(np.full_like(seq.images[0], np.nan), seq.dts[0])
    assert out.status_names() == ["initialising"] * n


def test_cold_solve_uses_the_estimators_acceptance_rule():
    seq = Sequences("paper", 3, 2, seed=2)
    batch, singles = seq.estimators(3)
    images = seq.images[0].copy()
    images[1] = np.random.default_rng(0).uniform(-1e-3, 1e-3, (4, 2))  # no consistent pose
    poses, accepted = batch.cold_solve(images)
    for image, pose, ok in zip(images, poses, accepted):
        sol = singles[0].solve(image, None)
        assert ok == (sol is not None)
        if sol is not None:
            np.testing.assert_allclose(pose, sol.pose, RTOL, STATE_ATOL)  # rounding (above)
    assert accepted.tolist() == [True, False, True]


def test_bad_inputs_are_refused():
    seq = Sequences("paper", 2, 1, seed=1)
    batch, _ = seq.estimators(2)
    with pytest.raises(ValueError, match="images"):
        batch.update(np.zeros((2, 3, 2)), np.full(2, 0.05))
    with pytest.raises(ValueError, match="dt"):
        batch.update(seq.images[0], np.array([0.05, -0.01]))
    batch.update(seq.images[0], np.array([0.05, -0.01]), np.array([True, False]))  # idle: fine


ESTIMATE_INFO = ("estimate_position_error", "estimate_velocity_error", "estimate_nees")


def _play_last(env, seeds: list[int], steps: int) -> list[np.ndarray]:
    """The last sub-env's observations and estimate errors over ``steps`` steps of slow, fixed
    actions (every sub-env the same), from a reset with ``seeds``."""
    i = env.num_envs - 1
    obs, _ = env.reset(seed=seeds)
    out = [obs[i]]
    action = np.tile([0.05, -0.02, 0.03], (env.num_envs, 1))
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(action)
        out += [obs[i], *(np.asarray(info[key][i]) for key in ESTIMATE_INFO)]
        if terminated[i] or truncated[i]:
            break
    return out


@pytest.mark.parametrize("n", [2, 3, 5])
def test_an_episode_plays_the_same_in_a_batch_of_any_size(n):
    """A filter's numbers do not depend on which other filters update in the same step: one
    seed's observations and estimate errors, step after step, are bitwise the same played alone
    and as the last of n sub-envs (a lone pose used to take numpy's matrix-vector product, and
    the last row of an odd number took BLAS's remainder kernel: both round differently)."""
    from capture_bench.envs.vector_env import CaptureVectorEnv
    from capture_bench.task.scenarios import load_scenario

    seeds = [int(s) for s in load_scenario("paper").validation_seeds[:n]]
    alone, batch = CaptureVectorEnv(1, "paper"), CaptureVectorEnv(n, "paper")
    try:
        got = _play_last(batch, seeds, 60)
        ref = _play_last(alone, seeds[-1:], 60)
    finally:
        alone.close()
        batch.close()
    assert len(got) == len(ref) > 100
    for step, (a, b) in enumerate(zip(got, ref, strict=True)):
        np.testing.assert_array_equal(a, b, err_msg=f"value {step}")


def test_a_snapshot_restored_elsewhere_continues_the_filters_bit_for_bit():
    """Two filters' state after 10 steps, restored into other rows of a larger estimator,
    gives the same 20 steps after it as the filters that were never moved."""
    seq = Sequences("noisy", 4, 30, seed=3)
    first, _ = seq.estimators(4)
    for k in range(10):
        first.update(seq.images[k], seq.dts[k])
    second, _ = seq.estimators(6)  # rows 5, 2 take first's rows 0, 3
    second.restore([5, 2], first.snapshot([0, 3]))
    for k in range(10, 30):
        a = first.update(seq.images[k], seq.dts[k])
        images = np.full((6, *seq.images.shape[2:]), np.nan)
        images[[5, 2]] = seq.images[k][[0, 3]]
        dts = np.zeros(6)
        dts[[5, 2]] = seq.dts[k][[0, 3]]
        b = second.update(images, dts, np.isin(np.arange(6), [5, 2]))
        for field in ("position", "velocity", "covariance", "valid", "status"):
            np.testing.assert_array_equal(getattr(b, field)[[5, 2]], getattr(a, field)[[0, 3]])


def _assert_rows_equal(a: Estimates, rows_a: list[int], b: Estimates, rows_b: list[int]) -> None:
    """Rows ``rows_a`` of ``a`` and ``rows_b`` of ``b`` are the same, bit for bit."""
    for field in ESTIMATE_FIELDS:
        np.testing.assert_array_equal(
            getattr(a, field)[rows_a], getattr(b, field)[rows_b], err_msg=field
        )


def _assert_filters_equal(a: TargetEstimator, i: int, b: TargetEstimator, j: int) -> None:
    """Row i of ``a`` holds the filter state of row j of ``b``, bit for bit."""
    for got, want in zip(a.snapshot([i]).__dict__.values(), b.snapshot([j]).__dict__.values()):
        np.testing.assert_array_equal(got, want)


def test_a_row_is_the_same_in_a_batch_of_any_size():
    """Each row's estimates and filter, step after step, are bitwise the same in a batch of 16,
    in a batch of 3 and alone (n = 1, given a mask: the one-row path), with drop-outs and
    latency."""
    n, steps = 16, 50
    seq = Sequences("noisy", n, steps, seed=4)
    big, _ = seq.estimators(n)
    small, _ = seq.estimators(3)
    alone = [seq.estimators(1)[0] for _ in range(3)]
    one = np.ones(1, dtype=bool)
    for k in range(steps):
        out = big.update(seq.images[k], seq.dts[k])
        _assert_rows_equal(
            small.update(seq.images[k, :3], seq.dts[k, :3]), [0, 1, 2], out, [0, 1, 2]
        )
        for i, est in enumerate(alone):
            got = est.update(seq.images[k, i : i + 1], seq.dts[k, i : i + 1], one)
            _assert_rows_equal(got, [0], out, [i])
            _assert_filters_equal(est, 0, big, i)
    assert (big.initialised & ~big.diverged).all()


@pytest.mark.parametrize("rule", ["update", "predict"])
def test_the_one_row_path_is_a_row_of_a_batch_bit_for_bit(rule, monkeypatch):
    """n = 1 whose row steps takes `_update_one`; it gives each row the numbers the row has in a
    batch of 6, bit for bit, through partial frames, lost frames and each divergence rule (the
    NIS, a non-finite covariance, S not positive definite, a prior behind the lens, frames no
    pose explains)."""
    n, steps = 6, 45
    seq = Sequences("paper", n, steps, seed=11)
    rng = np.random.default_rng(8)
    for i in range(n):
        for _ in range(5):
            start, length = rng.integers(0, steps), rng.integers(1, 6)
            hidden = rng.choice(4, size=rng.integers(1, 5), replace=False)  # 4: no frame
            seq.images[start : start + length, i, hidden] = np.nan
    half = seq.model.half_extent
    seq.images[25:, 0] += 40 * seq.model.pixel_pitch  # the target jumps: the NIS rule
    seq.images[25:, 5] = rng.uniform(-0.5, 0.5, seq.images[25:, 5].shape) * half  # garbage
    seq.images[25, 1:5] = seq.images[24, 1:5]  # a complete frame at the step of the faults
    seq.images[[8, 9, 30], 1:5] = np.nan  # lost frames
    seq.images[:2, 0] = np.nan  # no frame at first: initialising
    seq.images[:3, 1, 2] = np.nan  # a marker hidden at first: initialising too
    batch, _ = seq.estimators(n, partial_frames=rule)
    ones = [seq.estimators(1, partial_frames=rule)[0] for _ in range(n)]
    calls = []
    for est in ones:
        one_path = est._update_one
        monkeypatch.setattr(est, "_update_one", lambda *a, f=one_path: calls.append(1) or f(*a))
    statuses = set()
    for k in range(steps):
        if k == 25:
            for est, i in ((batch, 1), (ones[1], 0)):
                est.P[i, 0, 0] = np.nan  # non-finite covariance
            for est, i in ((batch, 2), (ones[2], 0)):
                est.P[i] = -np.eye(12)  # S not positive definite
            for est, i in ((batch, 3), (ones[3], 0)):
                est.x[i, BLOCK_ORDER.tolist().index(3)] = -40.0  # behind the lens
        out = batch.update(seq.images[k], seq.dts[k])
        statuses |= set(out.status_names())
        for i, est in enumerate(ones):
            _assert_rows_equal(
                est.update(seq.images[k, i : i + 1], seq.dts[k, i : i + 1]), [0], out, [i]
            )
            _assert_filters_equal(est, 0, batch, i)
    assert len(calls) == n * steps
    assert statuses == set(STATUSES), statuses
    assert batch.reinitialisations[:4].tolist() == [1, 1, 1, 1], batch.reinitialisations
    assert batch.diverged[5] and not batch.diverged[:5].any()


@pytest.mark.parametrize("source", ["photogrammetry", "truth"])
def test_the_ablation_sources_equal_the_reference_per_row(source):
    """Photogrammetry (warm starts, finite-difference velocity, held solutions) and truth at
    n = 5, with drop-outs, latency, partial frames and an active mask: each row equals its
    reference estimator, the status sequence exactly."""
    n, steps = 5, 40
    seq = Sequences("noisy", n, steps, seed=6)
    seq.images[10:13, 1, 2] = np.nan  # a partial frame: no photogrammetry
    batch, singles = seq.estimators(n, source=source)
    rng = np.random.default_rng(2)
    statuses = []
    for k in range(steps):
        active = rng.random(n) < 0.8
        truth = (rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
        out, row_statuses = step_both(batch, singles, seq.images[k], seq.dts[k], active, truth)
        statuses += [s for s in row_statuses if s is not None]
        if source == "truth":
            np.testing.assert_array_equal(out.position[active], truth[0][active])
            np.testing.assert_array_equal(out.velocity[active], truth[1][active])
        assert np.isnan(out.covariance).all() and not out.valid[~active].any()
    expected = {"ok"} if source == "truth" else {"initialising", "ok", "predicting"}
    assert set(statuses) == expected
