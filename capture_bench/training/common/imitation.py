"""Imitation before reinforcement: DAgger (Ross, Gordon & Bagnell 2011) from an analytic
controller, then the run's own algorithm goes on from the imitated policy.

With ``imitate: <controller>`` (one of `TEACHERS`: deterministic, built from the task's
public description; in a mixture, also a controller per scenario,
``{default: <controller>, <scenario>: <controller>}``: `teacher_names`), a new run first plays
``imitation_rounds`` rounds of ``imitation_steps`` environment steps on its own training
envs (training seeds only). Every visited observation is labelled with the controller's action
(the teacher's, built from each scenario's public description, so a mixture's sub-envs each get
their scenario's); round 0 follows the teacher, the later rounds follow the policy being trained
(deterministic actions), so the data set also holds the states the policy itself reaches,
DAgger's point. After each round the policy's mean action is fitted to the labels of every round
so far (mean squared error, Adam at ``imitation_lr`` on minibatches of ``imitation_batch``,
``imitation_epochs`` passes; with ``imitation_floor`` > 0 each
label's error is taken relative to the teacher's action above that floor,
`label_weights`). The policy then acts alone: nothing of the controller is left in it,
unlike a residual (`capture_bench.training.common.residual_vec_env`). The fit sets an
actor-critic's mean action (PPO, A2C) or an off-policy actor's deterministic action (SAC, TQC: the
``tanh`` of its mean, against the controller's action scaled to [-1, 1]), `IMITATORS`.

With pixels (``observation_source: pixels``, the batched training env) the student sees the
image and the arm's state while the teacher reads the estimate-fed observation of the same env
step (`capture_bench.envs.vector_env.CaptureVectorEnv.estimate_observation`: the scenario's
estimator, which runs beside the pixels for ``info``): each visited pixel observation is labelled
with the controller's action on that step's estimate. The controller acts as it would in the
estimate-fed env; only the student's input differs. Behind a front end (``front_end``,
`capture_bench.training.common.front_end_vec_env`) the student's observation is the front end's
vector of that step's image and state.

With ``imitation_state_weight`` w > 0 (pixels, PPO and A2C) the fit also asks the student's
features to say what the teacher reads: a linear head from the actor's features to that step's
estimate-fed observation (each of its 16 entries standardised over the data set) adds w times
its mean squared error to the action's loss (`StateTargets`). The label of every rendered frame
is then 16 numbers, the target's position and velocity among them, not the 3 of an action whose
error says little of where the target is; the head shapes the features extractor during the
fit and is not part of the policy (the policy saved and evaluated is the same network as
without it).

With the ``marker_keypoints`` features extractor
(`capture_bench.agents.marker_reader.MarkerKeypointExtractor`) the extractor's standardisation is
set from the data set before each round's fit, and with ``imitation_keypoint_weight`` w > 0 (PPO
and A2C) the fit also asks its reader for the markers where they are: on each labelled step the
env's true image points of the target's markers (`CaptureVectorEnv.true_image_points`) are the
targets of the newest frame's keypoints, w times their robust pixel error (`keypoint_loss`)
plus the detection logits' cross-entropy (`KeypointTargets`). The reader reads every frame of
the stack alike, so the newest frame's targets teach it for all of them.

Each complete round is kept on disk (`capture_bench.training.common.imitation_progress`): a run
stopped during its imitation goes on from its last complete round.

``imitation_warmup`` environment steps of the algorithm follow with the actor frozen
(`FrozenActor`), so the critic, still untrained, learns the imitated policy's values
before its advantages move the actor (off-policy: before its Q-values move the actor; the
replay buffer starts empty, and SB3's first ``learning_starts`` steps act at random unless
``use_sde_at_warmup`` lets the gSDE policy act).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from capture_bench.training.config.hyperparameters import IMITATION_DEFAULTS

if TYPE_CHECKING:
    from capture_bench.training.common.imitation_progress import RoundStore

#: The algorithms whose policy the fit can set: an actor-critic's mean (PPO, A2C), an off-policy
#: actor's deterministic squashed action (SAC, TQC).
IMITATORS = ("ppo", "a2c", "sac", "tqc")

#: Adam's learning rate and minibatch size for the imitation fit where a run leaves them out
#: (``imitation_lr``, ``imitation_batch``): right for a policy on the 16 numbers of the
#: observation; a convolutional student of pixels needs smaller steps (docs/pixels.md).
IMITATION_LR = IMITATION_DEFAULTS["imitation_lr"]
IMITATION_BATCH = IMITATION_DEFAULTS["imitation_batch"]

#: N observations (N, 16) -> the teacher's N actions (N, 3)
Teacher = Callable[[np.ndarray], np.ndarray]


def teacher_names(imitate: str | dict[str, str], scenarios: Sequence[str]) -> list[str]:
    """The controller each of ``scenarios`` imitates: ``imitate`` itself (a controller name), or
    its entry in a mapping of scenario names (and ``default``, for the scenarios it does not name)
    to controller names.

    Raises:
        ConfigError: the mapping names a scenario outside ``scenarios``, or leaves one without a
            controller and has no ``default``.
    """
    from capture_bench.validation import ConfigError

    if isinstance(imitate, str):
        return [imitate] * len(scenarios)
    unknown = sorted(set(imitate) - {"default", *scenarios})
    if unknown:
        raise ConfigError(
            f"imitate names {unknown[0]!r}, which is not a scenario of this run; valid keys: "
            f"default, {', '.join(scenarios)}"
        )
    missing = [name for name in scenarios if name not in imitate and "default" not in imitate]
    if missing:
        raise ConfigError(
            f"imitate gives scenario {missing[0]!r} no controller; name it, or add default: "
            "<controller> for the scenarios the mapping leaves out"
        )
    return [imitate.get(name, imitate.get("default", "")) for name in scenarios]


def describe_teacher(imitate: str | dict[str, str]) -> str:
    """``imitate`` in words: ``incremental_ik``, or ``incremental_ik_uncapped (grasp:
    incremental_ik)`` for a mapping whose default is the first controller."""
    if isinstance(imitate, str):
        return imitate
    others = ", ".join(f"{k}: {v}" for k, v in imitate.items() if k != "default")
    if "default" not in imitate:
        return others
    return imitate["default"] + (f" ({others})" if others else "")


def make_teacher(
    names: Sequence[str], descriptions: Sequence[Any], shares: Sequence[int]
) -> Teacher:
    """The controllers for the training envs: the first ``shares[0]`` rows act with controller
    ``names[0]`` built from ``descriptions[0]``, the next ``shares[1]`` with ``names[1]`` from
    ``descriptions[1]``, and so on (one scenario: one name and description, all rows)."""
    from capture_bench.agents.residual import TEACHERS, make_base

    controllers = [make_base(n, d, TEACHERS) for n, d in zip(names, descriptions, strict=True)]
    bounds = np.cumsum([0, *shares])

    def act(observations: np.ndarray) -> np.ndarray:
        rows = [
            np.asarray(c.predict(observations[lo:hi])[0], dtype=np.float32)
            for c, lo, hi in zip(controllers, bounds[:-1], bounds[1:], strict=True)
        ]
        return np.concatenate(rows)

    return act


def mean_actions(policy: Any, observations: Any) -> Any:
    """The policy's deterministic actions in its own action space, a torch tensor with grad: an
    actor-critic's mean (before clipping, in the env's units); an off-policy actor's squashed
    action (SAC's and TQC's ``tanh`` of the mean, in [-1, 1]: `policy_targets`)."""
    if _has_actor(policy):
        return policy.actor(observations, deterministic=True)
    return policy.get_distribution(observations).distribution.mean


def policy_targets(policy: Any, actions: np.ndarray) -> np.ndarray:
    """The controller's ``actions`` (the env's units) where `mean_actions` puts the policy's:
    unchanged for an actor-critic; clipped to the action space and scaled to [-1, 1] for a policy
    that squashes its output (SB3's ``scale_action``, which its ``predict`` undoes)."""
    if not policy.squash_output:
        return actions
    space = policy.action_space
    return policy.scale_action(np.clip(actions, space.low, space.high)).astype(np.float32)


def _has_actor(policy: Any) -> bool:
    """Whether ``policy`` acts through an actor network of its own (SAC, TQC)."""
    return getattr(policy, "actor", None) is not None


def label_weights(targets: np.ndarray, floor: float) -> np.ndarray | None:
    """Each label's weight in the fit: None (all equal, plain MSE) for ``floor`` 0, else
    1 / (||a||^2 + floor^2) scaled to a mean of 1, so the fit minimises the error relative to the
    teacher's action ``a`` wherever ||a|| is above ``floor``: the small last steps onto the capture
    point count as much as the full-speed ones."""
    if floor <= 0:
        return None
    w = 1.0 / (np.sum(np.square(targets, dtype=np.float64), axis=1) + floor**2)
    return (w / w.mean()).astype(np.float32)


def _stacked(observations: list[Any]) -> Any:
    """The rows of a list of batches: one array, or with pixels one array per key (each keeping
    its dtype: images stay uint8)."""
    if isinstance(observations[0], dict):
        return {key: np.concatenate([o[key] for o in observations]) for key in observations[0]}
    return np.concatenate(observations)


def _copied(obs: Any) -> Any:
    """A batch of observations kept for the data set: float32, or with pixels each key copied."""
    if isinstance(obs, dict):
        return {key: np.array(value) for key, value in obs.items()}
    return np.array(obs, dtype=np.float32)


def _tensor(x: Any, device: Any) -> Any:
    """The data set on ``device``: a float32 tensor, or a dict of tensors (images as uint8: the
    policy's preprocessing scales them)."""
    import torch

    if isinstance(x, dict):
        return {key: torch.as_tensor(value, device=device) for key, value in x.items()}
    return torch.as_tensor(x, dtype=torch.float32, device=device)


def _rows(x: Any, batch: Any) -> Any:
    return {key: value[batch] for key, value in x.items()} if isinstance(x, dict) else x[batch]


@dataclass
class StateTargets:
    """The auxiliary regression of `fit`: ``head`` (a ``torch.nn.Linear`` from the actor's
    features to the teacher's observation), ``targets`` (N, 16), the teacher's observation of
    each row of the data set, standardised, and ``weight`` w of its mean squared error;
    ``last_mse``, set by `fit`: that error over the last epoch (1 is the targets' variance)."""

    head: Any
    targets: np.ndarray
    weight: float
    last_mse: float | None = None


@dataclass
class KeypointTargets:
    """The keypoint supervision of `fit`: ``points`` (N, F, 2), where each row's markers lie in
    the newest frame of its wide image, pixels, and ``weight`` w of the keypoints' loss;
    ``last_px``, set by `fit`: the keypoints' median pixel error over the last epoch."""

    points: np.ndarray
    weight: float
    last_px: float | None = None


def _marker_extractor(policy: Any) -> Any:
    """The actor's features extractor where it reads the markers (``marker_keypoints``), else
    None."""
    from capture_bench.agents.marker_reader import MarkerKeypointExtractor

    extractor = getattr(policy, "pi_features_extractor", None)
    return extractor if isinstance(extractor, MarkerKeypointExtractor) else None


def _preprocessed(policy: Any, observations: Any) -> Any:
    """``observations`` as the policy's features extractor reads them (SB3's preprocessing: the
    images scaled to [0, 1] where the policy normalises them)."""
    from stable_baselines3.common.preprocessing import preprocess_obs

    return preprocess_obs(observations, policy.observation_space, policy.normalize_images)


def _keypoint_loss(extractor: Any, images: Any, points: Any) -> tuple[Any, Any]:
    """The newest frames' keypoints (of ``images`` preprocessed, `_preprocessed`) against
    ``points`` (B, F, 2): their robust pixel error (`keypoint_loss`) plus the detection logits'
    cross-entropy (`heatmap_loss`), points outside the image counting nothing; and the pixel
    errors of the points inside."""
    import torch

    from capture_bench.agents.marker_reader import heatmap_loss, keypoint_loss

    pixels, _, logits = extractor.read(images)
    size = images.shape[-1]
    inside = torch.all((points >= 0) & (points <= size - 1), dim=-1).float()
    loss = keypoint_loss(pixels, points, inside) + heatmap_loss(logits, points, inside)
    error = torch.linalg.vector_norm(pixels.detach() - points, dim=-1)
    return loss, error[inside > 0]


def _standardise(policy: Any, extractor: Any, observations: Any, seed: int) -> None:
    """Set a ``marker_keypoints`` extractor's standardisation from up to 2,048 rows of the data
    set, preprocessed as the policy reads them."""
    import torch

    n = len(next(iter(observations.values())))
    index = np.sort(np.random.default_rng(seed).choice(n, min(n, 2048), replace=False))
    rows = {k: torch.as_tensor(v[index], device=policy.device) for k, v in observations.items()}
    extractor.standardise(_preprocessed(policy, rows))


def standardised(rows: np.ndarray) -> np.ndarray:
    """``rows`` (N, D) less their mean over N, over their standard deviation (1 where it is
    below 1e-6: a constant entry stays 0), float32."""
    x = np.asarray(rows, dtype=np.float64)
    std = x.std(axis=0)
    return ((x - x.mean(axis=0)) / np.where(std < 1e-6, 1.0, std)).astype(np.float32)


def _state_head(policy: Any, size: int, seed: int) -> Any:
    """A linear map from ``policy``'s actor features to ``size`` numbers, seeded."""
    import torch

    with torch.random.fork_rng():  # torch's global stream stays where the run has it
        torch.manual_seed(seed)
        head = torch.nn.Linear(policy.features_dim, size)
    return head.to(policy.device)


def _actions_and_state(policy: Any, observations: Any, head: Any) -> tuple[Any, Any]:
    """`mean_actions` of an actor-critic and ``head`` of the same features (one pass of the
    actor's features extractor)."""
    from stable_baselines3.common.policies import BaseModel

    features = BaseModel.extract_features(policy, observations, policy.pi_features_extractor)
    latent = policy.mlp_extractor.forward_actor(features)
    return policy._get_action_dist_from_latent(latent).distribution.mean, head(features)


def fit(
    policy: Any,
    observations: Any,
    targets: np.ndarray,
    epochs: int,
    seed: int,
    floor: float = 0.0,
    lr: float = IMITATION_LR,
    batch_size: int = IMITATION_BATCH,
    state: StateTargets | None = None,
    keypoints: KeypointTargets | None = None,
) -> float:
    """Fit the policy's mean action on ``observations`` (an array, or with pixels a dict of
    arrays) to ``targets`` (squared error, weighted by
    `label_weights` of ``floor``; Adam at ``lr`` on the actor's parameters, minibatches of
    ``batch_size`` in a seeded order), with ``state`` also its auxiliary regression (module
    docstring; the head's parameters join Adam's) and with ``keypoints`` its reader's keypoints
    (module docstring); return the last epoch's mean loss of the action (the auxiliaries' not
    included)."""
    import torch

    extractor = _marker_extractor(policy)
    if keypoints is not None:
        if extractor is None:
            raise ValueError("keypoint targets need the marker_keypoints features extractor")
        kp = torch.as_tensor(keypoints.points, dtype=torch.float32, device=policy.device)
    if extractor is not None:
        _standardise(policy, extractor, observations, seed)
    params = list(actor_parameters(policy))
    if state is not None:
        params += list(state.head.parameters())
        s = torch.as_tensor(state.targets, device=policy.device)
    optimizer = torch.optim.Adam(params, lr=lr)
    rng = np.random.default_rng(seed)
    x = _tensor(observations, policy.device)
    y = torch.as_tensor(policy_targets(policy, targets), dtype=torch.float32, device=policy.device)
    weights = label_weights(targets, floor)
    w = None if weights is None else torch.as_tensor(weights[:, None], device=policy.device)
    policy.set_training_mode(True)
    loss_sum = state_sum = 0.0
    errors: list[Any] = []
    for _ in range(epochs):
        order = torch.as_tensor(rng.permutation(len(y)), device=policy.device)
        loss_sum = state_sum = 0.0
        errors = []
        for start in range(0, len(y), batch_size):
            batch = order[start : start + batch_size]
            if state is None:
                actions = mean_actions(policy, _rows(x, batch))
            else:
                actions, said = _actions_and_state(policy, _rows(x, batch), state.head)
            squared = (actions - y[batch]) ** 2
            loss = torch.mean(squared if w is None else w[batch] * squared)
            total = loss
            if state is not None:
                state_loss = torch.mean((said - s[batch]) ** 2)
                total = loss + state.weight * state_loss
                state_sum += state_loss.item() * len(batch)
            if keypoints is not None:
                image = _preprocessed(policy, {"image": x["image"][batch]})["image"]
                kp_loss, error = _keypoint_loss(extractor, image, kp[batch])
                total = total + keypoints.weight * kp_loss
                errors.append(error)
            optimizer.zero_grad()
            total.backward()
            optimizer.step()
            loss_sum += loss.item() * len(batch)
    policy.set_training_mode(False)
    if state is not None:
        state.last_mse = state_sum / len(y)
    found = torch.cat(errors) if errors else torch.zeros(0)
    if keypoints is not None and found.numel():  # none: every marker outside the image
        keypoints.last_px = float(found.median())
    return loss_sum / len(y)


def actor_parameters(policy: Any) -> list[Any]:
    """The parameters that shape the policy's action and not the critic's value: the actor's
    layers, the action head, the log std, and the features extractor where the actor has its own
    (SB3's ``share_features_extractor=False``) or it is shared with the critic; an off-policy
    policy's actor network whole (SAC's and TQC's own features extractor included)."""
    import torch

    if _has_actor(policy):
        return list(policy.actor.parameters())
    extractor = getattr(policy, "pi_features_extractor", policy.features_extractor)
    found = [
        *extractor.parameters(),
        *policy.mlp_extractor.policy_net.parameters(),
        *policy.action_net.parameters(),
    ]
    if isinstance(getattr(policy, "log_std", None), torch.nn.Parameter):
        found.append(policy.log_std)
    return found


def dagger(  # noqa: PLR0913
    model: Any,
    venv: Any,
    teacher: Teacher,
    rounds: int,
    steps: int,
    epochs: int,
    seed: int,
    log: Callable[[str], None] = print,
    validate: Callable[[], dict[str, float]] | None = None,
    floor: float = 0.0,
    teacher_view: Callable[[Any], np.ndarray] | None = None,
    lr: float = IMITATION_LR,
    batch_size: int = IMITATION_BATCH,
    state_weight: float = 0.0,
    store: RoundStore | None = None,
    keypoint_weight: float = 0.0,
    keypoint_view: Callable[[], np.ndarray] | None = None,
) -> dict[str, Any]:
    """DAgger on ``venv`` (the raw training envs, auto-resetting): see the module docstring
    (``floor``, ``lr``, ``batch_size``: the fit's, `fit`; ``teacher_view``: what the teacher
    reads of the step whose observation the student sees, ``teacher_view(obs)``; None: the
    observation itself; ``state_weight`` > 0: the fit's auxiliary regression of what the teacher
    reads, `StateTargets`; ``keypoint_weight`` > 0: the fit's keypoint supervision,
    `KeypointTargets`, on the points ``keypoint_view()`` gives for each step, (num_envs, F, 2)).
    Returns what it did: rounds, environment steps, data set size, each round's fit loss and the
    share of the round's actions on which policy and teacher agree within 0.05 in every joint
    (None for round 0, where the teacher acts), with ``state_weight`` each round's error of the
    regression of the teacher's observation (``state_mse``, a share of its variance), with
    ``keypoint_weight`` each round's median keypoint error (``keypoint_px``, pixels), the wall
    clock, s, and with ``validate`` (the run's validation: pooled statistics of the policy on
    validation seeds) the policy's validation after each round and the wall clock then, its
    learning curve (``validations``).

    With ``store`` each complete round is kept on disk, and a store that holds rounds already
    (a run stopped during its imitation) is gone on from: the data set, the policy and the log as
    they were after its last round, the next round on freshly reset envs
    (`capture_bench.training.common.imitation_progress`)."""
    from capture_bench.training.common.imitation_progress import Progress

    start = time.perf_counter()
    per_round = max(1, math.ceil(steps / venv.num_envs))
    done, head_state = (Progress(), None) if store is None else store.load(model.policy)
    observations, labels, views = done.observations, done.labels, done.views
    points = done.points
    head = None
    if done.rounds:
        if state_weight > 0:
            head = _state_head(model.policy, views[0].shape[1], seed)
            if head_state is not None:
                head.load_state_dict(head_state)
        if keypoint_weight > 0 and sum(map(len, points)) != sum(map(len, labels)):
            from capture_bench.training.common.checkpoint import CheckpointError

            raise CheckpointError(
                f"imitation_keypoint_weight {keypoint_weight:g}: the kept rounds hold no keypoint "
                "targets for every row; resume with the weight they were made with, or remove "
                "the run's imitation_progress folder to start the imitation again"
            )
        log(f"imitation: {done.rounds} of {rounds} rounds done before; going on from there")
    obs = venv.reset()
    for r in range(done.rounds, rounds):
        close = []
        first_row = len(labels)
        for _ in range(per_round):
            seen = obs if teacher_view is None else teacher_view(obs)
            target = teacher(seen)
            observations.append(_copied(obs))
            labels.append(target)
            if state_weight > 0:
                views.append(np.array(seen, dtype=np.float32))
            if keypoint_weight > 0:
                points.append(np.asarray(keypoint_view(), dtype=np.float32))
            if r == 0:
                action = target
            else:
                action, _ = model.policy.predict(obs, deterministic=True)
                close.append(np.all(np.abs(action - target) <= 0.05, axis=1))
            obs, _, _, _ = venv.step(np.asarray(action, dtype=np.float32))
        state = None
        if state_weight > 0:
            if head is None:
                head = _state_head(model.policy, views[0].shape[1], seed)
            state = StateTargets(head, standardised(np.concatenate(views)), state_weight)
        marks = None
        if keypoint_weight > 0:
            marks = KeypointTargets(np.concatenate(points), keypoint_weight)
        loss = fit(model.policy, _stacked(observations), np.concatenate(labels), epochs,
                   seed + r, floor, lr, batch_size, state, marks)  # fmt: skip
        done.losses.append(loss)
        if state is not None and state.last_mse is not None:
            done.state_losses.append(state.last_mse)
        if marks is not None and marks.last_px is not None:
            done.keypoint_px.append(marks.last_px)
        done.agreement.append(float(np.mean(np.concatenate(close))) if close else None)
        rows = sum(len(label) for label in labels)
        note = "" if r == 0 else f", policy within 0.05 of the teacher on {done.agreement[-1]:.0%}"
        if validate is not None:
            stats = validate()
            keys = ("capture_rate", "median_ratio_to_limit", "mean_score")
            wall = round(done.elapsed_s + time.perf_counter() - start, 1)
            found = {k: _finite(stats[k]) for k in keys}
            done.curve.append({"environment_steps": rows, **found, "wall_time_s": wall})
            note += (f"; validation capture rate {stats['capture_rate']:.2f}, median ratio "
                     f"{stats['median_ratio_to_limit']:.2f}")  # fmt: skip
        said = ""
        if done.state_losses:
            said = f" (the teacher's observation: {done.state_losses[-1]:.3f} of its variance)"
        if done.keypoint_px:
            said += f" (keypoints: {done.keypoint_px[-1]:.2f} px median)"
        log(f"imitation round {r + 1}/{rounds}: {rows} labelled steps, fit MSE {loss:.2e}{said}"
            f"{note}")  # fmt: skip
        if store is not None:
            done.rounds = r + 1
            store.save(_with_elapsed(done, start), first_row, model.policy, head)
    return {
        "rounds": rounds,
        "environment_steps": rounds * per_round * venv.num_envs,
        "labelled_steps": sum(len(label) for label in labels),
        "fit_mse": done.losses,
        "agreement": done.agreement,
        **({"state_mse": done.state_losses} if done.state_losses else {}),
        **({"keypoint_px": done.keypoint_px} if done.keypoint_px else {}),
        "wall_time_s": round(done.elapsed_s + time.perf_counter() - start, 1),
        **({"validations": done.curve} if validate is not None else {}),
    }


def _with_elapsed(done: Any, start: float) -> Any:
    """``done`` as it is to be stored: its wall clock with this session's time so far added."""
    import dataclasses

    return dataclasses.replace(done, elapsed_s=done.elapsed_s + time.perf_counter() - start)


def _finite(value: float) -> float | None:
    """``value`` as a float, None for NaN (JSON has no NaN)."""
    return None if math.isnan(value) else float(value)


class FrozenActor(BaseCallback):
    """Keep the actor's parameters (`actor_parameters`) out of the algorithm's updates for
    the first ``steps`` environment steps of the run: only the critic learns meanwhile."""

    def __init__(self, steps: int) -> None:
        super().__init__()
        self.steps = int(steps)
        self._frozen: bool | None = None

    def _set(self, frozen: bool) -> None:
        if frozen != self._frozen:
            for p in actor_parameters(self.model.policy):
                p.requires_grad_(not frozen)
            self._frozen = frozen

    def _on_training_start(self) -> None:
        self._on_rollout_start()

    def _on_rollout_start(self) -> None:
        self._set(self.num_timesteps < self.steps)

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self._set(False)
