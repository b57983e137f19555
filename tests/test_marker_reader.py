"""The markers' reader (capture_bench.agents.marker_reader): the centroid of area-sampled coverage
is a disc's sub-pixel centre, the heatmap loss is least at the true points' shares, the colour
channels ignore shading, the reader learns synthetic markers to a tenth of a pixel, and the
``marker_keypoints`` extractor reads each frame alike, standardises, and trains, stores and loads
through train.py."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import train
from capture_bench.agents.marker_reader import (
    MARKERS,
    MIN_STD,
    ROBUST_PX,
    MarkerKeypointExtractor,
    MarkerReader,
    colour_channels,
    feature_width,
    heatmap_loss,
    keypoint_loss,
    local_centroid,
    window_pixels,
)
from capture_bench.agents.sb3_policy import load_policy, read_metadata
from capture_bench.envs.capture_env import CaptureEnv
from capture_bench.sim.markers import MARKER_COLOURS
from tests.stored_policies import assert_loads_safely_and_acts_as_trusted

SIZE = 36


def _area_sampled_disc(centre, radius, shape, m=21):
    """How much of each pixel (pixel centres at whole numbers) a disc covers, (H, W)."""
    h, w = shape
    ys, xs = np.mgrid[0 : h * m, 0 : w * m]
    inside = np.hypot((xs + 0.5) / m - 0.5 - centre[0], (ys + 0.5) / m - 0.5 - centre[1]) <= radius
    return inside.reshape(h, m, w, m).mean(axis=(1, 3))


def test_the_local_centroid_finds_an_area_sampled_discs_sub_pixel_centre():
    """A marker 3.3 pixels across (the wide view's at 1.2 m), area-sampled: the centroid of the
    coverage itself is its centre to a thousandth of a pixel, where a softmax of the same
    map over the same window at temperature 1 is half a pixel off; a window given elsewhere
    reads there."""
    centre = np.array([20.37, 11.71])
    disc = torch.as_tensor(_area_sampled_disc(centre, 1.65, (30, 40)), dtype=torch.float32)
    maps = torch.stack((disc, torch.roll(disc, 9, dims=1)))[None]  # (1, 2, 30, 40)
    found, mass = local_centroid(maps, 3)
    np.testing.assert_allclose(found[0, 0].numpy(), centre, atol=0.002)
    np.testing.assert_allclose(found[0, 1].numpy(), centre + [9, 0], atol=0.002)
    np.testing.assert_allclose(mass[0].numpy(), np.pi * 1.65**2, rtol=0.01)
    rows, cols, values = window_pixels(maps, 3)
    soft = torch.softmax(values[0, 0], -1)
    soft_xy = np.array([(soft * cols[0, 0]).sum().item(), (soft * rows[0, 0]).sum().item()])
    assert np.linalg.norm(soft_xy - centre) > 0.5
    peak = torch.tensor([[12 * 40 + 30, 12 * 40 + 20]])  # the first map read around (30, 12)
    found, mass = local_centroid(maps, 3, peak)
    np.testing.assert_allclose(found[0, 0].numpy(), [30, 12], atol=1e-4)  # nothing there: centre
    assert mass[0, 0] == 0.0


def test_the_heatmap_loss_is_least_at_the_points_bilinear_shares():
    points = torch.tensor([[[3.25, 4.5], [0.0, 6.0]]])  # (1, 2, 2): x, y
    shares = torch.zeros(1, 2, 8, 8)
    shares[0, 0, 4, 3], shares[0, 0, 4, 4] = 0.375, 0.125  # (1 - fx)(1 - fy), fx (1 - fy)
    shares[0, 0, 5, 3], shares[0, 0, 5, 4] = 0.375, 0.125
    shares[0, 1, 6, 0] = 1.0
    best = torch.log(shares + 1e-12)
    inside = torch.ones(1, 2)
    entropy = -(0.75 * np.log(0.375) + 0.25 * np.log(0.125)) / 2  # the second map: 0
    assert abs(heatmap_loss(best, points, inside).item() - entropy) < 1e-4
    for shifted in (torch.roll(best, 1, dims=3), torch.zeros_like(best), best * 0.5):
        assert heatmap_loss(shifted, points, inside) > heatmap_loss(best, points, inside)
    assert heatmap_loss(torch.zeros_like(best), points, torch.zeros(1, 2)) == 0.0


def test_colour_channels_do_not_change_with_shading():
    red = torch.tensor([0.9, 0.2, 0.1])[None, :, None, None]
    lit, shaded = colour_channels(red), colour_channels(0.5 * red)
    assert lit.shape == (1, 10, 1, 1)
    np.testing.assert_allclose(lit[:, 3:].numpy(), shaded[:, 3:].numpy(), atol=2e-3)
    np.testing.assert_allclose(lit[0, 3, 0, 0].item(), (0.9 - 0.1) / 0.9, atol=2e-3)


def _synthetic(n, rng, size=24):
    """``n`` frames (n, 3, size, size) in [0, 1] as the scene renders them: the markers' colours
    as area-sampled discs 3.3 pixels across, each randomly lit, at random sub-pixel places on a
    white background, and a grey, randomly lit cross (the block's colour) between them, inside
    their windows; and the centres (n, MARKERS, 2)."""
    colours = np.array([c[:3] for c in MARKER_COLOURS])
    images = np.empty((n, 3, size, size), dtype=np.float32)
    centres = np.empty((n, MARKERS, 2), dtype=np.float32)
    half = size // 2
    for i in range(n):
        image = np.ones((3, size, size), dtype=np.float64)
        image[:, half - 1 : half + 1, :] = rng.uniform(0.3, 0.6)
        image[:, :, half - 1 : half + 1] = rng.uniform(0.3, 0.6)
        for k in range(MARKERS):  # one quadrant each: the discs never touch each other or the cross
            corner = np.array([k % 2, k // 2]) * half
            centres[i, k] = corner + rng.uniform(3.0, half - 3.5, 2)
            cover = _area_sampled_disc(centres[i, k], 1.65, (size, size), m=9)
            shade = rng.uniform(0.6, 1.0)  # the lit side or the shaded
            image = image * (1 - cover) + cover * (shade * colours[k])[:, None, None]
        images[i] = image
    return torch.as_tensor(images), torch.as_tensor(centres)


def test_the_robust_keypoint_loss_is_the_squared_error_near_and_levels_off_far():
    points = torch.zeros(1, 3, 2)
    near = torch.tensor([[[0.05, 0.0], [0.0, 0.1], [0.0, 0.0]]])
    inside = torch.ones(1, 3)
    squared = (near**2).sum(-1)
    expected = (squared / (squared + ROBUST_PX**2)).mean()
    torch.testing.assert_close(keypoint_loss(near, points, inside), expected)
    assert keypoint_loss(near, points, inside) < (squared.mean() / ROBUST_PX**2) * 1.001
    far = torch.tensor([[[5.0, 0.0], [0.0, 50.0], [0.0, 0.0]]])
    assert 0.6 < keypoint_loss(far, points, inside) < 2 / 3  # two of three near 1, one 0
    assert keypoint_loss(far, points, torch.tensor([[0.0, 0.0, 1.0]])) == 0.0  # outside: nothing


def _fitted_reader(images, centres, squared=False):
    """A reader fitted as the pixel student's keypoints are (the heatmap loss places the window,
    `keypoint_loss`, or with ``squared`` the plain squared pixel error, shapes the weights): 400
    steps of 32 frames."""
    torch.manual_seed(0)
    reader = MarkerReader()
    optimizer = torch.optim.Adam(reader.parameters(), lr=1e-2)
    inside = torch.ones(32, MARKERS)
    for step in range(400):
        index = torch.as_tensor(np.random.default_rng(step).choice(len(images), 32, replace=False))
        pixels, _, logits = reader(images[index])
        if squared:
            error = ((pixels - centres[index]) ** 2).sum(-1).mean()
        else:
            error = keypoint_loss(pixels, centres[index], inside)
        loss = heatmap_loss(logits, centres[index], inside) + error
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return reader


def test_the_reader_learns_the_markers_to_a_tenth_of_a_pixel():
    """The reader finds markers it has not seen to < 0.1 px at the median beside the grey cross
    in their windows, where the window's centre alone is off by ~0.5 px."""
    rng = np.random.default_rng(0)
    train_x, train_p = _synthetic(256, rng)
    test_x, test_p = _synthetic(64, rng)
    reader = _fitted_reader(train_x, train_p)
    with torch.no_grad():
        pixels, mass, logits = reader(test_x)
    error = torch.linalg.vector_norm(pixels - test_p, dim=-1)
    assert torch.all(error.median(0).values < 0.1), error.median(0).values  # every marker
    peak = logits.flatten(2).argmax(-1)
    window_centre = torch.stack((peak % 24, peak // 24), -1).float()
    assert torch.linalg.vector_norm(window_centre - test_p, dim=-1).median() > 0.3
    assert torch.all(mass > 0)


def _hidden(images, centres, rng, share=0.3):
    """The frames with a grey square over each marker in ``share`` of them (its centre still the
    target, as the env's true image points give a hidden marker), and which are hidden."""
    images = images.clone()
    hidden = torch.as_tensor(rng.random(centres.shape[:2]) < share)
    for i, k in zip(*np.nonzero(hidden.numpy()), strict=True):
        x, y = centres[i, k].round().long().tolist()
        images[i, :, max(y - 3, 0) : y + 4, max(x - 3, 0) : x + 4] = 0.5
    return images, hidden


def test_hidden_markers_do_not_pull_the_robust_fit_off_the_visible_ones():
    """With a third of the markers hidden and their centres still the targets, the robust fit
    reads the visible markers to < 0.04 px at the median, at least twice as close as a fit of
    the squared error, which the hidden markers' pixels of error pull."""
    rng = np.random.default_rng(0)
    train_x, train_p = _synthetic(256, rng)
    test_x, test_p = _synthetic(64, rng)
    train_x, _ = _hidden(train_x, train_p, rng)
    test_x, hidden = _hidden(test_x, test_p, rng)
    worst = {}
    for squared in (False, True):
        reader = _fitted_reader(train_x, train_p, squared)
        with torch.no_grad():
            pixels, _, _ = reader(test_x)
        error = torch.linalg.vector_norm(pixels - test_p, dim=-1)
        worst[squared] = max(error[~hidden[:, k], k].median().item() for k in range(MARKERS))
    assert worst[False] < 0.04, worst
    assert worst[False] < worst[True] / 2, worst


def test_the_reader_weighs_the_windows_pixels_as_its_maps_of_the_whole_frame_do():
    """The reader computes the weights at its windows' pixels alone: the same keypoints and
    weights as the whole frame's weight maps read in the same windows."""
    torch.manual_seed(1)
    reader = MarkerReader()
    frames = torch.rand(4, 3, 30, 40)
    pixels, mass, logits = reader(frames)
    peak = logits.flatten(2).argmax(-1)
    whole, whole_mass = local_centroid(reader.weight_maps(frames), reader.window, peak)
    torch.testing.assert_close(pixels, whole)
    torch.testing.assert_close(mass, whole_mass)


def _pixel_space(**options):
    with CaptureEnv("paper", observation_source="pixels", image_size=(SIZE,) * 2,
                    **options) as env:  # fmt: skip
        space = env.observation_space
        obs, _ = env.reset(seed=3)
        for _ in range(2):
            obs = env.step(np.full(3, 0.5, dtype=np.float32))[0]
    return space, {k: torch.as_tensor(v[None]).float() / (255 if v.dtype == np.uint8 else 1)
                   for k, v in obs.items()}  # fmt: skip


def test_the_extractor_reads_each_frame_alike_oldest_first_and_standardises():
    space, obs = _pixel_space(frame_stack=3)
    extractor = MarkerKeypointExtractor(space)
    width = feature_width(MARKERS)
    assert extractor.features_dim == 3 * width + 7
    newest = obs["image"][:, -3:]  # three frames that differ, oldest first
    obs["image"] = torch.cat([newest.flip(-1), torch.roll(newest, 9, dims=-2), newest], dim=1)
    batch = {k: torch.cat([v, v.flip(-1)]) for k, v in obs.items()}  # two rows
    with torch.no_grad():
        features = extractor(batch)
        for f in range(3):  # frame f's features: the reader's of that frame alone
            pixels, mass, _ = extractor.reader(batch["image"][:, 3 * f : 3 * f + 3])
            single = extractor.raw({"image": batch["image"][:, 3 * f : 3 * f + 3].repeat(1, 3, 1, 1),
                                    "state": batch["state"]})  # fmt: skip
            torch.testing.assert_close(features[:, f * width : (f + 1) * width],
                                       single[:, :width])  # fmt: skip
        torch.testing.assert_close(features[:, -7:], batch["state"])
        newest, _, _ = extractor.read(batch["image"])
        torch.testing.assert_close(newest, pixels)
    many = {k: v.repeat(8, *([1] * (v.dim() - 1))) for k, v in batch.items()}
    many["image"] = many["image"] * torch.linspace(0.5, 1.0, 16)[:, None, None, None]
    many["state"] = many["state"] + torch.randn(16, 7)
    extractor.standardise(many)
    with torch.no_grad():
        x, raw = extractor(many), extractor.raw(many)
    np.testing.assert_allclose(x.mean(0).numpy(), 0.0, atol=1e-4)
    torch.testing.assert_close(x, (raw - raw.mean(0)) / raw.std(0).clamp_min(MIN_STD))
    assert torch.all(x.std(0)[raw.std(0) > 0.1] > 0.95)
    assert "mean" in extractor.state_dict() and "std" in extractor.state_dict()


def test_the_extractor_refuses_the_crop_in_one_line():
    space, _ = _pixel_space(ee_crop=37)
    with pytest.raises(ValueError, match="ee_crop") as caught:
        MarkerKeypointExtractor(space)
    assert "\n" not in str(caught.value)


PIXELS = ["--observation-source", "pixels", "--config", "configs/pixels/ppo.yaml"]
TINY = ["n_envs=2", "n_steps=16", "batch_size=16", "n_epochs=1", "policy_kwargs.net_arch=[8]",
        f"image_size={SIZE}", "total_timesteps=32", "checkpoint_freq=0", "eval_freq=0",
        "frame_stack=2", "policy_kwargs.features_extractor=marker_keypoints"]  # fmt: skip


def test_a_run_with_marker_keypoints_stores_a_plain_policy_that_loads_safely(tmp_path):
    run = tmp_path / "run"
    sets = [*TINY, "imitate=dls", "imitation_steps=32", "imitation_rounds=1",
            "imitation_epochs=1"]  # fmt: skip
    assert train.main([*PIXELS, *(f"--set={s}" for s in sets), "--run-dir", str(run)]) == 0
    meta = json.loads((run / "metadata.json").read_text())
    assert meta["policy_kwargs"]["features_extractor"] == "marker_keypoints"
    assert_loads_safely_and_acts_as_trusted(run)


@pytest.mark.parametrize(
    ("more", "expected"),
    [
        (["ee_crop=37", "imitate=dls"], "ee_crop"),
        (["asymmetric_critic=true", "imitate=dls"], "asymmetric_critic"),
        ([], "set imitate"),
    ],
)
def test_what_marker_keypoints_cannot_take_is_one_line(tmp_path, capsys, more, expected):
    args = [*PIXELS, *(f"--set={s}" for s in [*TINY, *more]), "--run-dir", str(tmp_path / "r")]
    assert train.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "marker_keypoints" in err and expected in err
    assert not (tmp_path / "r").exists()


# -- the reader fitted in DAgger to where the markers are --------------------------------------


def test_the_envs_true_image_points_are_where_view_points_puts_the_markers():
    from capture_bench.engine.task import CaptureTask
    from capture_bench.envs.vector_env import CaptureVectorEnv
    from capture_bench.task.scenarios import load_scenario

    options = {"image_supersample": 3, "ee_crop": 37, "ee_crop_scale": 3}
    env = CaptureVectorEnv(3, "paper", observation_source="pixels", **options)
    imager = CaptureTask(load_scenario("paper"), observation_source="pixels", **options).imager()
    try:
        env.reset(seed=5)
        for _ in range(3):
            obs = env.step(np.full((3, 3), 0.3, dtype=np.float32))[0]
        found, features = env.true_image_points(), env.true_features()
        for i in range(3):
            expected = imager.view_points(features[i], obs["state"][i, 3:6].astype(float))
            np.testing.assert_array_equal(found[i], expected["image"])
    finally:
        imager.close()
        env.close()
    assert found.shape == (3, MARKERS, 2) and np.all((found > 0) & (found < 83))


def _marker_model(n_envs: int):
    from stable_baselines3 import PPO

    from capture_bench.training.common.sb3_vec_env import CaptureSB3VecEnv

    venv = CaptureSB3VecEnv(n_envs, "paper", seed=0, observation_source="pixels", frame_stack=2,
                            image_supersample=3)  # fmt: skip
    policy_kwargs = {"net_arch": [16], "features_extractor_class": MarkerKeypointExtractor}
    model = PPO("MultiInputPolicy", venv, n_steps=32, batch_size=32, n_epochs=1, seed=0,
                policy_kwargs=policy_kwargs, device="cpu")  # fmt: skip
    return model, venv


def test_dagger_fits_the_readers_keypoints_to_the_markers_true_image_points(monkeypatch):
    """Each labelled step's targets are where its newest frame shows the markers (the
    detector's centroids, independent of the projection); the fit sets the extractor's
    standardisation from the data set and brings the keypoints to the targets."""
    from capture_bench.sensing.detector import detect_markers
    from capture_bench.task.episode import describe_task
    from capture_bench.task.scenarios import load_scenario
    from capture_bench.training.common import imitation

    model, venv = _marker_model(2)
    teacher = imitation.make_teacher(["dls"], [describe_task(load_scenario("paper"))], [2])
    passed = []
    raw_fit = imitation.fit

    def spying_fit(policy, observations, targets, *args, **kwargs):
        passed.append((observations, targets, args))
        return raw_fit(policy, observations, targets, *args, **kwargs)

    def points():
        return venv.env_method("true_image_points", indices=[0])[0]

    def view(_obs):
        return venv.env_method("estimate_observation", indices=[0])[0]

    monkeypatch.setattr(imitation, "fit", spying_fit)
    try:
        done = imitation.dagger(model, venv, teacher, rounds=1, steps=64, epochs=1, seed=0,
                                log=lambda line: None, teacher_view=view, keypoint_weight=1.0,
                                keypoint_view=points)  # fmt: skip
    finally:
        venv.close()
    observations, targets, (epochs, seed, floor, lr, batch, state, marks) = passed[0]
    assert marks.weight == 1.0 and marks.points.shape == (64, MARKERS, 2)
    gaps = []  # a marker the block hides in part is found off its centre: most are not
    for i in range(0, 64, 3):
        newest = np.ascontiguousarray(observations["image"][i, -3:].transpose(1, 2, 0))
        found = detect_markers(newest, None, min_area=1, min_fill=0.0)
        gaps += [np.linalg.norm(found.pixels[k] - marks.points[i, k]) for k in range(MARKERS)
                 if found.found[k]]  # fmt: skip
    assert len(gaps) > 40 and np.median(gaps) < 0.25 and np.mean(np.less(gaps, 0.5)) > 0.8
    assert len(done["keypoint_px"]) == 1 and np.isfinite(done["keypoint_px"][0])
    extractor = model.policy.pi_features_extractor
    assert torch.any(extractor.mean != 0) and torch.any(extractor.std != 1)

    def error() -> float:
        with torch.no_grad():
            images = torch.as_tensor(observations["image"])
            pixels, _, _ = extractor.read(images.float() / 255.0)
        return float(torch.linalg.vector_norm(pixels - torch.as_tensor(marks.points), dim=-1)
                     .median())  # fmt: skip

    before = error()
    raw_fit(model.policy, observations, targets, 60, seed, floor, 1e-2, 16, None, marks)
    assert error() < 0.5 * before, (before, error())
    assert marks.last_px is not None and marks.last_px < before


def test_a_round_store_keeps_the_keypoint_targets(tmp_path):
    from capture_bench.training.common.imitation_progress import Progress, RoundStore

    policy = torch.nn.Linear(4, 2)
    store = RoundStore(tmp_path / "rounds")
    done = Progress(rounds=1, observations=[np.zeros((2, 3), np.float32)],
                    labels=[np.zeros((2, 3), np.float32)],
                    points=[np.arange(16, dtype=np.float32).reshape(2, 4, 2)],
                    losses=[0.1], agreement=[None], keypoint_px=[0.7])  # fmt: skip
    store.save(done, 0, policy)
    back, _ = store.load(policy)
    np.testing.assert_array_equal(back.points[0], done.points[0])
    assert back.keypoint_px == [0.7]


def test_a_run_fits_the_markers_keypoints_through_train_py(tmp_path):
    run = tmp_path / "run"
    sets = [*TINY, "imitate=dls", "imitation_steps=32", "imitation_rounds=2",
            "imitation_epochs=1", "imitation_keypoint_weight=1"]  # fmt: skip
    assert train.main([*PIXELS, *(f"--set={s}" for s in sets), "--run-dir", str(run)]) == 0
    done = json.loads((run / "imitation.json").read_text())
    assert done["rounds"] == 2 and len(done["keypoint_px"]) == 2
    assert all(np.isfinite(done["keypoint_px"]))
    saved = json.loads((run / "config.json").read_text())["hyperparameters"]
    assert saved["imitation_keypoint_weight"] == 1
    metadata = read_metadata(run)  # the policy stored and loaded with its standardisation
    state = load_policy(metadata).policy.state_dict()
    assert torch.any(state["pi_features_extractor.mean"] != 0)


def test_keypoint_targets_without_the_markers_reader_are_refused_in_one_line(tmp_path, capsys):
    sets = [s for s in TINY if "features_extractor" not in s]
    sets += ["imitate=dls", "imitation_keypoint_weight=1"]
    args = [*PIXELS, *(f"--set={s}" for s in sets), "--run-dir", str(tmp_path / "r")]
    assert train.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "marker_keypoints" in err
    assert "imitation_keypoint_weight" in err and not (tmp_path / "r").exists()
