"""The memory side of one recall env: its bank, its writer, the prompt it builds and what it observes.

The decision env keeps one ``EpisodeMemory`` per env in the trainer process, beside the one
controller; the physics that feeds it frames runs elsewhere (``sb3_memret.envs.physics``).
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np
from gymnasium import spaces

from sb3_memret.envs.cabinet import check_layer
from sb3_memret.envs.physics import EnvFrame
from sb3_memret.memory.bank import MemoryBank
from sb3_memret.memory.encoder import EMBEDDING_DIM, MiniLMEncoder
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig, is_true_memory, seed_memories
from sb3_memret.memory.writer import BoundingBoxPredicateExtractor, EventCompiler, ViewPredicateExtractor
from sb3_memret.prompts import PromptTemplate, build_prompt, instruction_text, location_text

MODES = ("recall", "oracle", "none")
# where the placed objects' facts come from: the episode's placement (the seed's), or what the robot saw
MEMORY_SOURCES = ("seeded", "observed")
# keep-scores of a bank's entries at decision time t (the retention critic, or the fixed prior)
KeepScorer = Callable[[Sequence[MemoryEntry], int], np.ndarray]


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; expected one of {list(MODES)}")
    return mode


def check_memory_source(source: str) -> str:
    if source not in MEMORY_SOURCES:
        raise ValueError(f"unknown memory source {source!r}; expected one of {list(MEMORY_SOURCES)}")
    return source


def observation_space(capacity: int) -> spaces.Dict:
    """The decision observation: instruction and memory embeddings, slot mask, type ids, age, usage."""
    return spaces.Dict(
        instruction=spaces.Box(-1.0, 1.0, (EMBEDDING_DIM,), np.float32),
        memories=spaces.Box(-1.0, 1.0, (capacity, EMBEDDING_DIM), np.float32),
        mask=spaces.Box(0.0, 1.0, (capacity,), np.float32),
        type_ids=spaces.Box(0.0, len(MemoryType) - 1, (capacity,), np.float32),
        age=spaces.Box(0.0, np.inf, (capacity,), np.float32),
        usage=spaces.Box(0.0, np.inf, (capacity,), np.float32),
    )


class EpisodeMemory:
    """One env's bounded bank and rule-based writer across its episodes.

    ``start`` seeds the bank for a new episode from the simulator's t=0 state; ``choose`` and
    ``prompt`` turn the retriever's slots into the controller's prompt; ``observe`` writes what
    the simulator says after a chunk. Eviction asks ``keep_scorer`` (the retention critic).

    ``source="observed"``: no fact comes from the placement. The bank starts with decoys only,
    the observation phase's views (each drawer opened once, ``EnvFrame.look_in``) write where each
    object was seen, and during the episode the target's location is written only while a camera
    sees it (``ViewPredicateExtractor``).
    """

    def __init__(self, capacity: int, mode: str, encoder: MiniLMEncoder, keep_scorer: KeepScorer,
                 template: PromptTemplate, seeding: SeedingConfig | None = None, source: str = "seeded"):
        self.mode = check_mode(mode)
        self.source = check_memory_source(source)
        self.encoder, self.keep_scorer, self.template = encoder, keep_scorer, template
        self.seeding = seeding or SeedingConfig()
        self.bank = MemoryBank(capacity)
        self.extractor = BoundingBoxPredicateExtractor() if source == "seeded" else ViewPredicateExtractor()
        self.compiler = EventCompiler(encoder)
        self.t = 0
        self.layer = 1
        self.target = "cube"
        self.true_evicted = False

    def start(self, frame: EnvFrame, rng: np.random.Generator) -> None:
        """A new episode: the seeded memories (true facts and decoys; decoys and what the observation
        phase saw for ``observed``) are the bank at t = 0."""
        state = frame.state
        self.layer = check_layer(int(state.target_layer[0]))
        self.target = state.target_name()
        self.t, self.true_evicted = 0, False
        self.bank.clear()
        seeds = seed_memories(state.placed(), self.target, rng, self.seeding, facts=self.source == "seeded")
        vectors = self.encoder.encode([e.text for e in seeds])
        self._write([e.with_embedding(v) for e, v in zip(seeds, vectors)])
        self.compiler.reset()
        if self.source == "observed":
            if frame.look_in is None:
                raise RuntimeError("the observed-memory variant needs the reset frame's look_in views")
            self._write(self.compiler.update(ViewPredicateExtractor.look_in(frame.look_in, state.object_names[0]), 0))
        self.compiler.update(self._extract(frame), 0)

    def choose(self, slots: np.ndarray) -> list[MemoryEntry]:
        """The entries in ``slots`` (empty slots add nothing), each marked as used."""
        entries = self.bank.entries
        for s in slots[slots < len(entries)]:
            self.bank.mark_used(int(s))
        return [entries[s] for s in slots if s < len(entries)]

    def prompt(self, chosen: list[MemoryEntry]) -> str:
        """The controller's prompt: the instruction plus the chosen facts (or the mode's fixed text)."""
        instruction = instruction_text(self.target)
        if self.mode == "oracle":
            return build_prompt(instruction, [location_text(self.target, self.layer)], self.template)
        if self.mode == "none":
            return build_prompt(instruction, [], self.template)
        return build_prompt(instruction, [e.text for e in chosen], self.template)

    def observe(self, frame: EnvFrame) -> None:
        """After an executed chunk: write the facts that changed, age the bank."""
        self.t += frame.steps
        self._write(self.compiler.update(self._extract(frame), self.t))
        self.bank.age(self.t)

    def _extract(self, frame: EnvFrame) -> dict:
        return self.extractor.extract(frame if self.source == "observed" else frame.state)

    def _write(self, entries: list[MemoryEntry]) -> None:
        for entry in entries:
            outcome = self.bank.write(entry, lambda stored: self.keep_scorer(stored, self.t))
            if outcome.evicted is not None and self.is_true(outcome.evicted):
                self.true_evicted = True

    def instruction(self) -> str:
        """The text the retriever conditions on: the instruction (with the target's layer in oracle mode)."""
        instruction = instruction_text(self.target)
        if self.mode == "oracle":
            return build_prompt(instruction, [location_text(self.target, self.layer)], PromptTemplate((instruction,)))
        return instruction

    def is_true(self, entry: MemoryEntry) -> bool:
        return is_true_memory(entry, self.target, self.layer)

    def true_slot(self) -> int:
        return next((i for i, e in enumerate(self.bank.entries) if self.is_true(e)), -1)

    def retrieved_true(self, chosen: list[MemoryEntry]) -> bool:
        return any(self.is_true(e) for e in chosen)

    def observation(self) -> dict[str, np.ndarray]:
        view = self.bank.view()
        return {
            "instruction": self.encoder.encode_one(self.instruction()).astype(np.float32),
            "memories": view.embeddings,
            "mask": view.mask.astype(np.float32),
            "type_ids": view.type_ids.astype(np.float32),
            "age": view.age,
            "usage": view.usage,
        }

    def info(self, success: bool) -> dict[str, Any]:
        return {
            "true_slot": self.true_slot(),
            "true_evicted": self.true_evicted,
            "success": success,
            "target_layer": self.layer,
            "target": self.target,
            "memory_texts": [e.text for e in self.bank.entries],
        }


__all__ = ["EpisodeMemory", "KeepScorer", "MEMORY_SOURCES", "MODES", "check_memory_source", "check_mode",
           "observation_space"]
