"""An asymmetric actor-critic for PPO and A2C on pixels (Pinto et al. 2018): the actor sees what
the agent sees (the images and the arm's state), the critic also the true state.

With ``asymmetric_critic: true`` (train.py, pixels, the batched env) the training envs add to
each observation ``critic_state``: the estimate-fed observation's layout
(`capture_bench.task.observation`, 16 entries) with the target's *true* position and velocity in
place of the estimate (`capture_bench.envs.vector_env.CaptureVectorEnv.true_observation`),
privileged, for training only. The policy (`AsymmetricActorCriticPolicy`) has two features
extractors: the actor's reads every key but ``critic_state``, the critic's every key; its actor
and critic layers (``net_arch``'s ``pi`` and ``vf``) start from each.

What is stored (`actor_policy`) is a plain ``MultiInputPolicy`` (``share_features_extractor:
false``) on the observation without ``critic_state``: the trained actor whole, and the trained
critic with its inputs from the true state removed (a critic of the agent's observation alone:
not the one that trained the actor; evaluation reads the actor only). It loads and plays as any
pixel model. While training, the policy's own ``predict`` (the periodic validation, in envs
without ``critic_state``) fills ``critic_state`` with zeros, which the actor never reads.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.policies import MultiInputActorCriticPolicy
from stable_baselines3.common.torch_layers import MlpExtractor

from capture_bench.task.observation import OBSERVATION_SIZE

#: The key of the critic's privileged observation.
CRITIC_KEY = "critic_state"


def actor_space(space: spaces.Dict) -> spaces.Dict:
    """``space`` without the critic's key: what the actor (and the agent) observes."""
    return spaces.Dict({k: v for k, v in space.spaces.items() if k != CRITIC_KEY})


def critic_space(space: spaces.Dict) -> spaces.Dict:
    """``space`` with the critic's key, the true state: ``Box(-10, 10, (16,), float32)``."""
    box = spaces.Box(-10.0, 10.0, (OBSERVATION_SIZE,), np.float32)
    return spaces.Dict({**space.spaces, CRITIC_KEY: box})


class _TwoInputs(torch.nn.Module):
    """SB3's ``MlpExtractor`` with the actor's and the critic's layers on features of their
    own sizes (``pi_dim``, ``vf_dim``)."""

    def __init__(self, pi_dim: int, vf_dim: int, net_arch: Any, activation_fn: Any, device: Any):
        super().__init__()
        actor = MlpExtractor(pi_dim, net_arch, activation_fn, device)
        critic = MlpExtractor(vf_dim, net_arch, activation_fn, device)
        self.policy_net, self.value_net = actor.policy_net, critic.value_net
        self.latent_dim_pi, self.latent_dim_vf = actor.latent_dim_pi, critic.latent_dim_vf

    def forward(self, features: tuple[torch.Tensor, torch.Tensor]) -> tuple[Any, Any]:
        return self.forward_actor(features[0]), self.forward_critic(features[1])

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self.policy_net(features)

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.value_net(features)


class AsymmetricActorCriticPolicy(MultiInputActorCriticPolicy):
    """SB3's ``MultiInputPolicy`` whose critic alone reads ``critic_state`` (module docstring);
    its observation space holds the key, its features extractors are not shared."""

    def __init__(self, observation_space: spaces.Dict, *args: Any, **kwargs: Any) -> None:
        if CRITIC_KEY not in observation_space.spaces:
            raise ValueError(f"the asymmetric critic reads {CRITIC_KEY!r}, not in the observation")
        kwargs["share_features_extractor"] = False
        super().__init__(observation_space, *args, **kwargs)

    def make_features_extractor(self) -> Any:
        """The actor's: every key of the observation but ``critic_state``."""
        return self.features_extractor_class(
            actor_space(self.observation_space), **self.features_extractor_kwargs
        )

    def _build_mlp_extractor(self) -> None:
        self.vf_features_extractor = self.features_extractor_class(
            self.observation_space, **self.features_extractor_kwargs
        )
        self.mlp_extractor = _TwoInputs(
            self.features_dim,
            self.vf_features_extractor.features_dim,
            self.net_arch,
            self.activation_fn,
            self.device,
        )

    def predict(self, observation: Any, *args: Any, **kwargs: Any) -> Any:
        """SB3's ``predict``, where ``critic_state`` may be missing (an env without the truth:
        zeros, which the actor never reads)."""
        if isinstance(observation, dict) and CRITIC_KEY not in observation:
            rows = np.asarray(observation["state"]).shape[:-1]
            observation = {**observation, CRITIC_KEY: np.zeros((*rows, OBSERVATION_SIZE), "f4")}
        return super().predict(observation, *args, **kwargs)


def _feature_columns(extractor: Any, drop: str) -> torch.Tensor:
    """The columns of ``extractor``'s output (its sub-extractors' outputs side by side, in
    order, as ``CombinedExtractor``'s) that do not come from key ``drop``."""
    keep, start = [], 0
    for key, net in extractor.extractors.items():
        box = extractor._observation_space.spaces[key]
        with torch.no_grad():
            size = int(net(torch.zeros((1, *box.shape), device=extractor_device(net))).shape[1])
        if key != drop:
            keep.extend(range(start, start + size))
        start += size
    return torch.as_tensor(keep, dtype=torch.long)


def extractor_device(net: torch.nn.Module) -> torch.device:
    """Where ``net``'s parameters are (the CPU for a module without any)."""
    return next((p.device for p in net.parameters()), torch.device("cpu"))


def actor_policy(policy: AsymmetricActorCriticPolicy) -> MultiInputActorCriticPolicy:
    """The stored form of ``policy`` (module docstring): a plain ``MultiInputActorCriticPolicy``
    on the observation without ``critic_state``, features extractors not shared, with the
    trained actor and the trained critic less its inputs from ``critic_state``."""
    params = policy._get_constructor_parameters()
    params["observation_space"] = actor_space(policy.observation_space)
    plain = MultiInputActorCriticPolicy(**params, share_features_extractor=False)
    plain.to(policy.device)
    columns = _feature_columns(policy.vf_features_extractor, CRITIC_KEY).to(policy.device)
    trained = policy.state_dict()
    state = {}
    for key, target in plain.state_dict().items():
        value = trained[key]
        if value.shape != target.shape:  # the critic's first layer: drop the truth's columns
            value = value[:, columns]
        state[key] = value
    plain.load_state_dict(state)
    plain.set_training_mode(False)
    return plain
