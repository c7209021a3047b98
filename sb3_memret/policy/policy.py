"""MemoryRetrievalPolicy: an SB3 ActorCriticPolicy whose actor is the retriever and whose
critic is the retention scorer, acting through a Plackett-Luce distribution."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from sb3_memret.memory.encoder import EMBEDDING_DIM
from sb3_memret.memory.stores import TIMESCALES, units_per_timescale
from sb3_memret.policy.distributions import PlackettLuceDistribution, gumbel_noise
from sb3_memret.policy.networks import CONTEXT_LR_SCALE, HIDDEN, RETRIEVERS, RelevanceMLP, RetentionScorer, SetRetriever

BANK_KEYS = ("instruction", "memories", "mask", "type_ids", "age", "usage")
EXPLORATION = ("decision", "episode")


class BankExtractor(BaseFeaturesExtractor):
    """Passes the bank observation through unchanged: both networks read its arrays directly."""

    def __init__(self, observation_space: spaces.Dict):
        missing = [k for k in BANK_KEYS if k not in observation_space.spaces]
        if missing:
            raise ValueError(f"observation space lacks {missing}; MemoryRetrievalPolicy needs keys {list(BANK_KEYS)}")
        super().__init__(observation_space, features_dim=EMBEDDING_DIM)

    def forward(self, observations: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return observations


class MemoryRetrievalPolicy(ActorCriticPolicy):
    """Actor: retriever scores -> Plackett-Luce top-K at ``temperature``. The retriever is the seed's
    per-memory ``RelevanceMLP`` (``retriever="mlp"``) or the set-structured ``SetRetriever``
    (``"set"``: attention over the whole bank).
    Critic: the mean RetentionScorer keep-score over valid slots. When the observation carries the
    shaping potential (env ``observe_potential``), the value is that mean minus the potential: the
    shaped value is the unshaped one minus the potential (Ng et al., 1999), so the keep-scores model
    only what the task's future is worth, not how far the current task has got. ``age_unit`` is
    the unit of the memories' ages the env observes (``MemoryConfig.age_units``, ``sb3_memret.envs.configs``):
    one, or one per store's timescale where the observation carries each slot's store (``store_ids``, a memory of
    several stores), which the critic then reads too.

    ``predict(obs, deterministic=True)`` is greedy retrieval (top-K by score).

    ``exploration``: how PPO's collection draws the Plackett-Luce noise. ``"decision"`` (the seed's) draws
    fresh Gumbel noise at every decision, so a near-uniform retriever hands the controller a different
    memory every 8 steps and no episode follows any memory long enough to show what it is worth.
    ``"episode"`` draws one Gumbel vector per env and episode (``redraw_noise`` at each episode end), so
    an episode's retrievals agree while the scores do: each decision is still exactly a Plackett-Luce
    draw, and PPO's ratios use its probability, as SB3's gSDE does for Gaussian noise. Outside collection
    (``predict``) every draw is fresh.
    ``"episode"`` is the default: it held what it learned where ``"decision"`` learned and unlearned (the
    drawer's learned controller, above; RememberShape3's camera controller; on the tests' K = 2 toy task at 10x
    the paper's step and entropy bonus it fell back on 2 seeds of 4, episode draws on none:
    ``lab/2026-11-26-exploration-stability/exploration_stability.py``). Neither steadies SeqOfColors3, whose advantages favour the wrong
    facts (docs: tasks).

    ``retriever_lr_scale`` scales the retriever's learning rate against the critic's (0 freezes it: a
    warm-started retriever that must not drift while the retention critic learns).
    ``context_lr_scale`` (set retriever only; default ``CONTEXT_LR_SCALE``) scales its attention and context
    head's rate against its per-memory path's. Under Adam every parameter steps about the learning rate
    whatever its gradient, so the attention's ~260k parameters at full rate moved the policy two to five times
    further per update than the MLP (approx. KL, clip fraction) and it learned the drawer slower than the MLP
    it starts as; at a tenth it tracks the MLP early and adds its correction as the bank's context is learned.
    """

    def __init__(self, observation_space: spaces.Dict, action_space: spaces.MultiDiscrete, lr_schedule,
                 temperature: float = 0.5, hidden: int = HIDDEN, retriever: str = "mlp",
                 age_unit: str | dict[str, str] = "steps",
                 exploration: str = "episode", retriever_lr_scale: float = 1.0, context_lr_scale: float | None = None,
                 **kwargs: Any):
        if not isinstance(action_space, spaces.MultiDiscrete):
            raise ValueError(f"MemoryRetrievalPolicy needs a MultiDiscrete action space of slot indices, got {action_space}")
        if retriever not in RETRIEVERS:
            raise ValueError(f"unknown retriever {retriever!r}; expected one of {list(RETRIEVERS)}")
        if retriever_lr_scale < 0:
            raise ValueError(f"retriever_lr_scale must be >= 0 (0 freezes the retriever), got {retriever_lr_scale}")
        self.retriever_lr_scale = retriever_lr_scale
        if context_lr_scale is not None and retriever != "set":
            raise ValueError(f"context_lr_scale={context_lr_scale} applies to the set retriever's attention only; "
                             f"retriever={retriever!r} has none (use retriever: set, or drop context_lr_scale)")
        if context_lr_scale is not None and context_lr_scale < 0:
            raise ValueError(f"context_lr_scale must be >= 0 (0 freezes the attention), got {context_lr_scale}")
        self.context_lr_scale = context_lr_scale
        if exploration not in EXPLORATION:
            raise ValueError(f"unknown exploration {exploration!r}; expected one of {list(EXPLORATION)}")
        self.temperature = temperature
        self.exploration = exploration
        self.episode_noise: torch.Tensor | None = None  # (n_envs, N) while PPO collects with exploration="episode"
        self.hidden = hidden
        self.retriever_kind = retriever
        units_per_timescale(age_unit, TIMESCALES if isinstance(age_unit, str) else age_unit)  # each unit known
        self.age_unit = age_unit if isinstance(age_unit, str) else dict(age_unit)
        kwargs.setdefault("features_extractor_class", BankExtractor)
        kwargs.setdefault("optimizer_class", torch.optim.AdamW)
        kwargs["ortho_init"] = False
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build(self, lr_schedule) -> None:
        self.action_dist = PlackettLuceDistribution(len(self.action_space.nvec), self.temperature)
        self.retriever = SetRetriever(hidden=self.hidden) if self.retriever_kind == "set" else RelevanceMLP(hidden=self.hidden)
        self.retention = RetentionScorer(hidden=self.hidden, age_unit=self.age_unit,
                                         stores="store_ids" in self.observation_space.spaces)
        context = self.retriever.context_parameters()
        in_context = {id(p) for p in context}
        per_memory = [p for p in self.retriever.parameters() if id(p) not in in_context]
        in_retriever = {id(p) for p in self.retriever.parameters()}
        others = [p for p in self.parameters() if id(p) not in in_retriever]
        context_scale = self.retriever_lr_scale * (CONTEXT_LR_SCALE if self.context_lr_scale is None else self.context_lr_scale)
        lr = lr_schedule(1)
        groups = [(per_memory, self.retriever_lr_scale), (context, context_scale), (others, 1.0)]
        self.optimizer = self.optimizer_class(
            [{"params": params, "lr": lr * scale, "lr_scale": scale} for params, scale in groups if params],
            lr=lr, **self.optimizer_kwargs)

    def scores(self, features: dict[str, torch.Tensor]) -> torch.Tensor:
        """(B, N) retriever scores of every slot (empty slots included, they are masked later)."""
        if self.retriever_kind == "set":
            return self.retriever(features["instruction"], features["memories"], features["mask"] > 0.5)
        return self.retriever(features["instruction"], features["memories"])

    def _distribution(self, f: dict[str, torch.Tensor]) -> PlackettLuceDistribution:
        return self.action_dist.proba_distribution(self.scores(f), f["mask"] > 0.5)

    @property
    def potential_baseline(self) -> bool:
        """Whether the value subtracts the observed shaping potential."""
        return "potential" in self.observation_space.spaces

    def _value(self, f: dict[str, torch.Tensor]) -> torch.Tensor:
        value = self.retention.value(f["memories"], f["type_ids"].long(), f["age"], f["usage"], f["mask"] > 0.5,
                                     f.get("store_ids"))[:, None]
        return value - f["potential"] if self.potential_baseline else value

    def forward(self, obs, deterministic: bool = False):
        f = self.extract_features(obs)
        dist = self._distribution(f)
        if deterministic or self.episode_noise is None:
            actions = dist.get_actions(deterministic=deterministic)
        else:
            actions = dist.sample(self.episode_noise)
        return actions, self._value(f), dist.log_prob(actions)

    def redraw_noise(self, n_envs: int, env_ids: Any = None) -> None:
        """Episode exploration: new Gumbel noise for ``env_ids`` (default every env), whose episodes start
        now; a change in ``n_envs`` draws for every env."""
        slots = int(self.action_space.nvec[0])
        if self.episode_noise is None or self.episode_noise.shape[0] != n_envs or env_ids is None:
            self.episode_noise = gumbel_noise((n_envs, slots), self.device)
        elif len(env_ids):
            self.episode_noise[env_ids] = gumbel_noise((len(env_ids), slots), self.device)

    def evaluate_actions(self, obs, actions: torch.Tensor):
        f = self.extract_features(obs)
        dist = self._distribution(f)
        return self._value(f), dist.log_prob(actions), dist.entropy()

    def get_distribution(self, obs) -> PlackettLuceDistribution:
        return self._distribution(self.extract_features(obs))

    def predict_values(self, obs) -> torch.Tensor:
        return self._value(self.extract_features(obs))

    def retention_state_dict(self) -> dict[str, torch.Tensor]:
        """CPU copy of the retention weights, to push to the envs that evict with them."""
        return {k: v.detach().cpu().clone() for k, v in self.retention.state_dict().items()}

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(temperature=self.temperature, hidden=self.hidden, retriever=self.retriever_kind,
                    age_unit=self.age_unit, exploration=self.exploration, retriever_lr_scale=self.retriever_lr_scale,
                    context_lr_scale=self.context_lr_scale)
        return data


def saved_retriever(path: str | Path, kind: str = "mlp", hidden: int = HIDDEN) -> dict[str, torch.Tensor]:
    """The retriever weights saved in the model file ``path`` (say, trained on another task of the
    benchmark), to start a new run's retriever from. Refuses a file whose retriever is of another
    kind or size than ``kind`` and ``hidden`` rather than load part of it."""
    data, params, _ = load_from_zip_file(path, device="cpu")
    saved = (data or {}).get("policy_kwargs", {})
    if (saved.get("retriever", "mlp"), saved.get("hidden", HIDDEN)) != (kind, hidden):
        raise ValueError(f"{str(path)!r} holds a {saved.get('retriever', 'mlp')!r} retriever of hidden size "
                         f"{saved.get('hidden', HIDDEN)}; this run's is {kind!r} of hidden size {hidden}")
    state = {k.removeprefix("retriever."): v for k, v in (params or {}).get("policy", {}).items()
             if k.startswith("retriever.")}
    if not state:
        raise ValueError(f"{str(path)!r} holds no retriever weights: not a MemoryRetrievalPolicy model")
    return state
