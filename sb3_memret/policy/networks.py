"""The two small networks of the memory learner (sizes as in the paper, appendix A)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager

import numpy as np
import torch
from torch import nn

from sb3_memret.memory.encoder import EMBEDDING_DIM
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.stores import TIMESCALES, units_per_timescale

HIDDEN = 128
TYPE_EMBEDDING_DIM = 32
AGE_SCALES: dict[str, float] = {"steps": 100.0, "tasks": 1.0}  # per unit of AGE_UNITS
USAGE_SCALE = 10.0
CONTEXT_LR_SCALE = 0.1  # the set retriever's attention learns at this fraction of its per-memory path's rate
CONTEXT_SEED_OFFSET = 7919  # the set retriever's attention draws its initial weights from seed + this
RANKING_SEED_OFFSET = 104729  # the retention critic's ranking head draws its initial weights from seed + this


@contextmanager
def own_random_stream(offset: int) -> Iterator[None]:
    """Draw initial weights from the run's seed + ``offset`` and leave the global stream untouched, so a
    module added beside the others leaves every other weight and draw of a run of that seed as it was."""
    with torch.random.fork_rng(devices=[]):
        torch.default_generator.manual_seed((torch.initial_seed() + offset) % 2**63)
        yield


def mlp(in_dim: int, hidden: int = HIDDEN) -> nn.Sequential:
    return nn.Sequential(nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 1))


class RelevanceMLP(nn.Module):
    """Task-aware retriever: scores memory m for instruction g from ``[h_g, h_m, |h_g - h_m|, h_g * h_m]``."""

    def __init__(self, embedding_dim: int = EMBEDDING_DIM, hidden: int = HIDDEN):
        super().__init__()
        self.net = mlp(4 * embedding_dim, hidden)

    def forward(self, instruction: torch.Tensor, memories: torch.Tensor) -> torch.Tensor:
        """instruction (B, D), memories (B, N, D) -> scores (B, N)."""
        g = instruction.unsqueeze(1).expand_as(memories)
        x = torch.cat([g, memories, (g - memories).abs(), g * memories], dim=-1)
        return self.net(x).squeeze(-1)

    def context_parameters(self) -> list[nn.Parameter]:
        """None: each memory is scored alone (the set retriever's attention is what has its own rate)."""
        return []


class SetRetriever(nn.Module):
    """Set-structured retriever: the seed's per-memory score plus a correction read from the whole bank.

    Each slot's features are the seed MLP's hidden layers over ``[h_g, h_m, |h_g - h_m|, h_g * h_m]`` (the
    instruction g is in every token); its score is the MLP's head on them plus a context term: ``layers``
    rounds of pre-norm self-attention over the valid slots only (no positions: permuting the slots permutes
    the scores, and any bank size works), then a head that starts at zero. So at initialisation it scores
    exactly as the per-memory MLP and learns at its pace, and attention adds what only the rivals tell:
    the one fact among several that names the instructed object, or a newer fact over a stale one.
    (Attention alone, with the score read off its output, averaged the slots' features at the start and
    learned slower than the MLP.) The attention is initialised from its own random stream, so the global
    one advances as the MLP's does: a set run and an MLP run of the same seed start from the same weights
    (critic included) and draw the same exploration until the context head first moves, a paired comparison.
    """

    def __init__(self, embedding_dim: int = EMBEDDING_DIM, hidden: int = HIDDEN, layers: int = 2, heads: int = 4):
        super().__init__()
        self.pair = nn.Sequential(nn.Linear(4 * embedding_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU())
        self.score = nn.Linear(hidden, 1)
        with own_random_stream(CONTEXT_SEED_OFFSET):  # the context branch (see above)
            layer = nn.TransformerEncoderLayer(hidden, heads, dim_feedforward=2 * hidden, dropout=0.0,
                                               batch_first=True, norm_first=True)
            self.attention = nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)
            self.context = nn.Linear(hidden, 1)
        nn.init.zeros_(self.context.weight)
        nn.init.zeros_(self.context.bias)

    def context_parameters(self) -> list[nn.Parameter]:
        """The attention's and the context head's parameters (the policy gives them their own learning rate)."""
        return [*self.attention.parameters(), *self.context.parameters()]

    def forward(self, instruction: torch.Tensor, memories: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """instruction (B, D), memories (B, N, D), mask (B, N) of valid slots -> scores (B, N).

        Empty slots neither attend nor are attended to; a bank with no valid slot attends over
        all (its scores are masked by the distribution anyway).
        """
        g = instruction.unsqueeze(1).expand_as(memories)
        h = self.pair(torch.cat([g, memories, (g - memories).abs(), g * memories], dim=-1))
        valid = mask.bool() | ~mask.bool().any(-1, keepdim=True)
        context = self.attention(h, src_key_padding_mask=~valid)
        return (self.score(h) + self.context(context)).squeeze(-1)


RETRIEVERS = ("mlp", "set")


class RetentionScorer(nn.Module):
    """Task-agnostic keep-score of each memory from [h_m, type embedding, age/scale, usage/10].

    It never sees the instruction: it judges how valuable a memory is in general. A keep-score is the sum
    of two heads over the same features: the value head, whose mean over valid slots is the PPO value
    (fit by the value loss alone), and the ranking head, zero at the start and trained only by the
    calibration loss (``sb3_memret.policy.credit``). The argmin of their sum is evicted. Kept apart
    because a calibrated ranking must not move the value: keep-scores stretched to rank memories grow
    with usage, so a retrieval would raise the next state's value and earn an advantage the reward
    never paid (measured: the set retriever collapsed on the drawer with one shared head). ``age_unit``:
    ages in control steps (scale 100, the seed's) or in tasks (scale 1: episodes of a household,
    between which objects may move, so a fact's chance of being stale grows with its age in tasks); in a
    memory of several stores (``stores``), one unit per store's timescale may be given, and the critic also reads
    each memory's store: a timescale embedding added to its type embedding.
    """

    def __init__(self, embedding_dim: int = EMBEDDING_DIM, hidden: int = HIDDEN,
                 age_unit: str | Mapping[str, str] = "steps", stores: bool = False):
        super().__init__()
        if not isinstance(age_unit, str) and not stores:
            raise ValueError(f"age units per store ({dict(age_unit)!r}) need a memory of several stores (stores=True)")
        units = units_per_timescale(age_unit, age_unit if not isinstance(age_unit, str) else TIMESCALES)
        self.age_unit = age_unit if isinstance(age_unit, str) else dict(units)
        scales = [AGE_SCALES[units.get(t, "steps")] for t in TIMESCALES]
        self.register_buffer("age_scales", torch.tensor(scales, dtype=torch.float32), persistent=False)
        self.type_embedding = nn.Embedding(len(MemoryType), TYPE_EMBEDDING_DIM)
        self.store_embedding = nn.Embedding(len(TIMESCALES), TYPE_EMBEDDING_DIM) if stores else None
        self.net = mlp(embedding_dim + TYPE_EMBEDDING_DIM + 2, hidden)
        with own_random_stream(RANKING_SEED_OFFSET):
            self.ranking = mlp(embedding_dim + TYPE_EMBEDDING_DIM + 2, hidden)
        nn.init.zeros_(self.ranking[-1].weight)
        nn.init.zeros_(self.ranking[-1].bias)

    def _features(self, memories: torch.Tensor, type_ids: torch.Tensor, age: torch.Tensor, usage: torch.Tensor,
                  store_ids: torch.Tensor | None = None) -> torch.Tensor:
        kinds = self.type_embedding(type_ids.long())
        if self.store_embedding is not None:
            if store_ids is None:
                raise ValueError("this critic reads each memory's store (a memory of several stores): pass store_ids")
            stores = store_ids.long()
            kinds = kinds + self.store_embedding(stores)
            scale = self.age_scales[stores]
        else:
            scale = self.age_scales[TIMESCALES.index("episode")]
        return torch.cat([memories, kinds, (age / scale).unsqueeze(-1), (usage / USAGE_SCALE).unsqueeze(-1)], dim=-1)

    def forward(self, memories: torch.Tensor, type_ids: torch.Tensor, age: torch.Tensor, usage: torch.Tensor,
                store_ids: torch.Tensor | None = None) -> torch.Tensor:
        """memories (B, N, D), type_ids/age/usage (B, N) (and store_ids, with stores) -> keep-scores (B, N), the
        order eviction reads."""
        x = self._features(memories, type_ids, age, usage, store_ids)
        return (self.net(x) + self.ranking(x)).squeeze(-1)

    def score_entries(self, entries: Sequence[MemoryEntry], ages: np.ndarray, timescale: int | None) -> np.ndarray:
        """Keep-scores of one store's ``entries`` of these ``ages``, the store's ``timescale`` id given in a memory of
        several stores (None otherwise): what an env evicts by."""
        with torch.no_grad():
            mem = torch.as_tensor(np.stack([e.embedding for e in entries]))[None]
            types = torch.tensor([[int(e.type) for e in entries]])
            age = torch.as_tensor(np.asarray(ages, dtype=np.float32))[None]
            usage = torch.tensor([[float(e.usage_count) for e in entries]])
            stores = None if timescale is None else torch.full_like(types, int(timescale))
            if (stores is None) != (self.store_embedding is None):
                raise ValueError(f"a critic {'with' if self.store_embedding is not None else 'without'} a store "
                                 f"embedding was asked to score a store of timescale id {timescale!r}")
            return self(mem, types, age, usage, stores)[0].numpy()

    def calibration_scores(self, memories: torch.Tensor, type_ids: torch.Tensor, age: torch.Tensor,
                           usage: torch.Tensor, store_ids: torch.Tensor | None = None) -> torch.Tensor:
        """The keep-scores with the value head and the shared features detached: what the calibration loss
        trains, so that only the ranking head learns from it."""
        x = self._features(memories, type_ids, age, usage, store_ids).detach()
        return (self.net(x).detach() + self.ranking(x)).squeeze(-1)

    def value(self, memories, type_ids, age, usage, mask: torch.Tensor,
              store_ids: torch.Tensor | None = None) -> torch.Tensor:
        """(B,) mean value-head score over the valid slots: the critic's V(s)."""
        scores = self.net(self._features(memories, type_ids, age, usage, store_ids)).squeeze(-1)
        mask = mask.float()
        return (scores * mask).sum(-1) / mask.sum(-1).clamp(min=1.0)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        """A model saved before the ranking head existed loads with the head at its zero start, which
        leaves its keep-scores exactly as saved."""
        if not any(key.startswith(prefix + "ranking.") for key in state_dict):
            state_dict.update({prefix + "ranking." + k: v for k, v in self.ranking.state_dict().items()})
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
