"""The memory side of one recall env: its bank, its writer, the prompt it builds and what it observes.

The decision env keeps one ``EpisodeMemory`` per env in the trainer process, beside the one
controller; the physics that feeds it frames runs elsewhere (``sb3_memret.physics``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable, Sequence

import numpy as np
from gymnasium import spaces

from sb3_memret.envs.configs import MemoryConfig, check_mode
from sb3_memret.memory.bank import MemoryBank
from sb3_memret.memory.retention import FIXED_RULES
from sb3_memret.memory.stores import TIMESCALES, StoreSpec, store_index, timescale_id
from sb3_memret.memory.encoder import EMBEDDING_DIM, MiniLMEncoder
from sb3_memret.memory.schema import Key, MemoryEntry, MemoryType
from sb3_memret.memory.writer import EventCompiler
from sb3_memret.controllers.prompts import PromptTemplate, build_prompt
from sb3_memret.tasks import Task, make_task
from sb3_memret.tasks.base import EnvFrame, Episode

# keep-scores of a store's entries given their ages and the store's timescale id (None in a memory of one store):
# the retention critic's, or the type prior before it is trained
KeepScorer = Callable[[Sequence[MemoryEntry], np.ndarray, "int | None"], np.ndarray]


def observation_space(capacity: int, potential: bool = False, stores: bool = False) -> spaces.Dict:
    """The decision observation: instruction and memory embeddings, slot mask, type ids, age, usage;
    with ``potential``, also the shaping potential in reward units, (1 - gamma) * Phi(s), for the critic; with
    ``stores`` (a memory of several stores), each slot's store as its timescale id (``stores.TIMESCALES``)."""
    fields = dict(
        instruction=spaces.Box(-1.0, 1.0, (EMBEDDING_DIM,), np.float32),
        memories=spaces.Box(-1.0, 1.0, (capacity, EMBEDDING_DIM), np.float32),
        mask=spaces.Box(0.0, 1.0, (capacity,), np.float32),
        type_ids=spaces.Box(0.0, len(MemoryType) - 1, (capacity,), np.float32),
        age=spaces.Box(0.0, np.inf, (capacity,), np.float32),
        usage=spaces.Box(0.0, np.inf, (capacity,), np.float32),
    )
    if potential:
        fields["potential"] = spaces.Box(0.0, np.inf, (1,), np.float32)
    if stores:
        fields["store_ids"] = spaces.Box(0.0, len(TIMESCALES) - 1, (capacity,), np.float32)
    return spaces.Dict(fields)


class EpisodeMemory:
    """One env's bounded banks and rule-based writer across its episodes, for one ``task``.

    ``start`` seeds the bank for a new episode from the task's reset frame; ``choose`` and
    ``prompt`` turn the retriever's slots into the controller's prompt; ``observe`` writes what
    the task's writer reads from an executed chunk (at every control step it perceived). Eviction
    asks ``keep_scorer`` (the retention critic, or a fixed rule).

    Progress (a writer's TASK_PROGRESS facts: ``the red cube was touched.``) is the robot's working memory of
    what it has done this episode, not something to recall: it is kept beside the bank, the latest fact per key,
    and follows the chosen facts in every prompt (as the rollout's fixed conditions state it), so the retriever
    chooses among the cue's facts and the decoys alone, and one K serves tasks with and without progress.

    ``source="observed"``: no fact comes from the placement. The bank starts with decoys only, the
    observation phase (``Task.look_in``: the drawer opens each drawer once) writes where each object was
    seen, and during the episode the task's observed writer writes only what a camera sees.

    The memory is one store or several (``config.store_specs``; ``sb3_memret.memory.stores``), in slot order:
    each fact goes to the store of its timescale (``Task.timescale``: now, episode or lasting), and each store
    evicts its own entries by its own rule (``StoreSpec.retention``, else ``config.retention``: the critic, told
    the store's timescale, or a fixed rule) with ages in its own unit.
    A lasting store (observed only; a household's episodes; ``config.long_term_capacity`` in short) survives
    episode resets. What the task calls lasting (``Task.timescale``: where objects were seen in drawers) goes
    there, with the household's hearsay about other things each episode (``Task.hearsay``); instead of the whole
    observation phase the robot gets the household's glimpses (``Task.look_in``), so what it knows of the rest it
    saw in earlier episodes.
    Times run on across episodes. Age units: a memory's age is the control steps since it was
    written (``"steps"``) or the episodes, a household's tasks (``"tasks"``): objects move only between
    tasks, so a fact's age in tasks is what says how likely it is to be stale. Measured before the glimpse, so they count what retention kept:
    ``needed_fact_gone``, the target was seen since the household last rearranged (whether or not
    the store took the fact in), yet its fact is not in the store; ``target_fact_kept``, the store
    holds the target's true fact; ``stale_fact_kept``, it holds a fact placing the target elsewhere.
    """

    def __init__(self, config: MemoryConfig, mode: str, encoder: MiniLMEncoder, keep_scorer: KeepScorer,
                 template: PromptTemplate, task: Task | str):
        self.mode = check_mode(mode)
        self.task = make_task(task)
        self.source, self.seeding, self.retention = config.source, config.seeding, config.retention
        self.encoder, self.keep_scorer, self.template = encoder, keep_scorer, template
        self.specs: tuple[StoreSpec, ...] = config.store_specs
        self.stores: list[MemoryBank] = [MemoryBank(spec.capacity) for spec in self.specs]
        self.household = config.household
        if self.seeding.event_every:  # refused now, not at the first event, by a task that words none
            self.task.event_decoy(np.random.default_rng(0), 0, self.seeding)
        self.rng: np.random.Generator | None = None  # the episode's generator: its decoys, then its events
        self.episode = 0  # episodes started so far (a household's tasks)
        self.writer = self.task.writer(self.source)
        self.compiler = EventCompiler(encoder, self.writer.relations, self.task.wordings)
        self.clock = 0  # control steps of the earlier episodes (long-term times run on)
        self.t = 0
        self.truth: Episode | None = None  # the episode's ground truth (metrics only)
        self.progress: dict[Key, MemoryEntry] = {}  # working memory: the episode's progress facts by key
        self.true_evicted = False
        self.needed_fact_gone = self.target_fact_kept = self.stale_fact_kept = False
        self.seen_since_move: set[str] = set()

    @property
    def now(self) -> int:
        return self.clock + self.t

    @property
    def bank(self) -> MemoryBank:
        """The store that holds this episode's facts."""
        return self.stores[store_index("episode", self.specs)]

    @property
    def long_term(self) -> MemoryBank | None:
        """The store that outlives episodes (a household's), if there is one."""
        return next((store for store, spec in zip(self.stores, self.specs) if spec.survives_episodes), None)

    def start(self, frame: EnvFrame, rng: np.random.Generator, moved: bool = False) -> None:
        """A new episode: the seeded memories (true facts and decoys; decoys and what the observation
        phase saw for ``observed``) are the bank at t = 0. ``moved``: the household rearranged."""
        self.truth, self.rng = self.task.episode(frame), rng
        self.clock = self.clock + self.t if self.household else 0
        self.t, self.true_evicted = 0, False
        self.episode += 1
        for store, spec in zip(self.stores, self.specs):
            if not spec.survives_episodes:
                store.clear()
        self.progress.clear()
        seeds = self.task.seed_memories(frame, self.truth, rng, self.seeding, facts=self.source == "seeded")
        if self.household:
            if moved:
                self.seen_since_move.clear()
            seeds += self.task.hearsay(rng, self.now, self.seeding)
        self._write(self._encoded([replace(e, timestamp=self.now) for e in seeds]))
        if self.household:
            slots = [self.long_term.find(key) for key, _ in self.truth.true_facts]  # one fact per key
            kept = [self.long_term.entries[slot] for slot in slots if slot is not None]
            self.target_fact_kept = len(kept) == len(slots) and all(self.is_true(entry) for entry in kept)
            self.stale_fact_kept = any(not self.is_true(entry) for entry in kept)
            self.needed_fact_gone = self.target in self.seen_since_move and not self.target_fact_kept
        self.compiler.reset()
        if self.source == "observed":
            self._look_in(frame, rng)
        self._read(frame)

    def _look_in(self, frame: EnvFrame, rng: np.random.Generator) -> None:
        """The observation phase: write what the task's ``look_in`` says the robot saw."""
        self._write(self.compiler.update(self.task.look_in(frame, rng, household=self.household),
                                         self.now))

    def slot_entries(self) -> list[MemoryEntry | None]:
        """Every slot's entry in slot order, None for an empty one (up to the last filled slot)."""
        slots: list[MemoryEntry | None] = []
        for store in self.stores[:-1]:
            entries = store.entries
            slots += entries + [None] * (store.capacity - len(entries))
        slots += self.stores[-1].entries
        while slots and slots[-1] is None:
            slots.pop()
        return slots

    def choose(self, slots: np.ndarray) -> list[MemoryEntry]:
        """The entries in ``slots`` (empty slots add nothing), each marked as used."""
        chosen = []
        for s in (int(s) for s in slots):
            for store in self.stores:
                if s < store.capacity:
                    if s < len(store):
                        store.mark_used(s, self.now)
                        chosen.append(store.entries[s])
                    break
                s -= store.capacity
        return chosen

    @property
    def target(self) -> str:
        return self.truth.target

    def prompt(self, chosen: list[MemoryEntry]) -> str:
        """The controller's prompt: the instruction plus ``prompt_facts``."""
        return build_prompt(self.task.instruction(self.truth), self.prompt_facts(chosen), self.template)

    def prompt_facts(self, chosen: list[MemoryEntry]) -> list[str]:
        """The facts a prompt carries: the chosen ones (or the mode's fixed ones), then the progress written so far,
        in the order first written (an update keeps its place)."""
        if self.mode == "oracle":
            facts = self.task.facts_at("oracle", self.truth, self.t)
        else:
            facts = [] if self.mode == "none" else [e.text for e in chosen]
        return [*facts, *(entry.text for entry in self.progress.values())]

    def observe(self, frame: EnvFrame) -> int:
        """After an executed chunk: write the facts that changed, each at the control step it was read, and the event
        decoys due in the chunk (``SeedingConfig.event_every``); returns how many facts the writer wrote."""
        written = self._read(frame)
        every, start = self.seeding.event_every, self.t
        self.t += frame.steps
        if every:
            due = range(start // every + 1, self.t // every + 1)
            self._write(self._encoded([self.task.event_decoy(self.rng, self.clock + k * every, self.seeding)
                                       for k in due]))
        return written

    def _read(self, frame: EnvFrame) -> int:
        """Compile what the writer reads from ``frame``, the clock set to each reading's control step
        (counted from the chunk's start), so ages and evictions see the time it was read; returns how many
        facts changed."""
        start, written = self.t, 0
        for step, predicates in self.writer.read(frame):
            self.t = start + step
            entries = self.compiler.update(predicates, self.now)
            self._write(entries)
            written += len(entries)
        self.t = start
        return written

    def _encoded(self, entries: list[MemoryEntry]) -> list[MemoryEntry]:
        vectors = self.encoder.encode([e.text for e in entries]) if entries else []
        return [e.with_embedding(v) for e, v in zip(entries, vectors)]

    def store_for(self, entry: MemoryEntry) -> int:
        """The store ``entry`` goes to: that of its timescale (``Task.timescale``), or the nearest there is."""
        return store_index(self.task.timescale(entry), self.specs)

    def ages(self, entries: Sequence[MemoryEntry], unit: str) -> np.ndarray:
        """The entries' ages in ``unit``: control steps, or episodes since each was written."""
        if unit == "tasks":
            return np.array([self.episode - e.episode for e in entries], dtype=np.float32)
        return np.array([self.now - e.timestamp for e in entries], dtype=np.float32)

    def _keep_scores(self, store: int, entries: Sequence[MemoryEntry]) -> np.ndarray:
        """Keep-scores in ``store``: by its fixed rule, else by the critic, told the store's timescale when the
        memory has more than one."""
        spec = self.specs[store]
        rule = spec.retention or self.retention
        if rule in FIXED_RULES:
            return FIXED_RULES[rule](entries)
        timescale = timescale_id(spec.timescale) if len(self.specs) > 1 else None
        return self.keep_scorer(entries, self.ages(entries, spec.age_unit), timescale)

    def _write(self, entries: list[MemoryEntry]) -> None:
        for entry in entries:
            entry = replace(entry, episode=self.episode)
            if entry.type == MemoryType.TASK_PROGRESS:
                self.progress[entry.key] = entry
                continue
            index = self.store_for(entry)
            outcome = self.stores[index].write(entry, lambda stored: self._keep_scores(index, stored))
            if outcome.evicted is not None and self.is_true(outcome.evicted):
                self.true_evicted = True
            if self.specs[index].survives_episodes:  # seen, whether or not the store took it in
                self.seen_since_move.add(entry.entity)

    def instruction(self) -> str:
        """The text the retriever conditions on: the instruction (with the oracle's facts in oracle mode)."""
        instruction = self.task.instruction(self.truth)
        if self.mode == "oracle":
            template = replace(self.task.prompt_template, instructions=(instruction,))
            return build_prompt(instruction, self.task.facts_at("oracle", self.truth, self.t), template)
        return instruction

    def is_true(self, entry: MemoryEntry) -> bool:
        return self.truth.is_true(entry)

    def true_slots(self) -> list[int]:
        """The slots that hold one of the memories the controller needs (a sequence task needs several)."""
        return [i for i, e in enumerate(self.slot_entries()) if e is not None and self.is_true(e)]

    def facts_in_bank(self) -> bool:
        """Whether every memory the controller needs is in the bank (only then can a retrieval be right)."""
        return len(self.true_slots()) == len(self.truth.true_facts)

    def true_slot(self) -> int:
        """The first true slot once every needed memory is in the bank, else -1."""
        slots = self.true_slots()
        return slots[0] if slots and self.facts_in_bank() else -1

    def retrieved_true(self, chosen: list[MemoryEntry]) -> bool:
        """Whether ``chosen`` holds every memory the controller needs (a hit): a true entry for each true fact's key
        (a bank holds one entry per key; a task may count a value near the truth as true, ``Episode.is_true``)."""
        return {e.key for e in chosen if self.is_true(e)} == {key for key, _ in self.truth.true_facts}

    def observation(self) -> dict[str, np.ndarray]:
        views = [store.view(self.ages(store.entries, spec.age_unit)) for store, spec in zip(self.stores, self.specs)]
        observation = {
            "instruction": self.encoder.encode_one(self.instruction()).astype(np.float32),
            "memories": np.concatenate([v.embeddings for v in views]),
            "mask": np.concatenate([v.mask for v in views]).astype(np.float32),
            "type_ids": np.concatenate([v.type_ids for v in views]).astype(np.float32),
            "age": np.concatenate([v.age for v in views]),
            "usage": np.concatenate([v.usage for v in views]),
        }
        if len(self.specs) > 1:
            observation["store_ids"] = np.concatenate([np.full(spec.capacity, timescale_id(spec.timescale), np.float32)
                                                       for spec in self.specs])
        return observation

    def info(self, success: bool) -> dict[str, Any]:
        info = {
            "true_slot": self.true_slot(),
            "true_slots": self.true_slots(),
            "true_evicted": self.true_evicted,
            "success": success,
            "group": self.truth.group,
            "target": self.target,
            "memory_texts": [e.text if e is not None else "" for e in self.slot_entries()],
            **self.truth.details,
        }
        if self.household:
            info.update(needed_fact_gone=self.needed_fact_gone, target_fact_kept=self.target_fact_kept,
                        stale_fact_kept=self.stale_fact_kept)
        return info


__all__ = ["EpisodeMemory", "KeepScorer", "observation_space"]
