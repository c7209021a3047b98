"""A scripted touch controller for any MIKASA "touch the object the cue named" task.

``TouchController`` is expert.py's ``ScriptedTouchController`` (the same funnel approach, coasting
model and hold-still, inherited) with what it reads made parameters: which observation keys hold
the detector's positions and visibility (``extra/{key}_positions``, ``extra/{key}_visible``), which
prompt field names the target (``colour``, ``shape``), the words it was trained on (index i of the
vocabulary is candidate i of the detector), and its prompt template. With no fact, or a word outside
its vocabulary, it holds still (zero actions).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from sb3_memret.controllers.base import ControllerSpec, Obs, as_numpy
from sb3_memret.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.expert import CONTROL_DT, ScriptedTouchController, TouchGains, tcp_velocity


def named_word(parsed: ParsedPrompt, field: str) -> str | None:
    """The ``field`` word of the prompt's first fact that has one, or None."""
    return next((v for f in parsed.facts for k, v in f.fields if k == field), None)


class TouchController(ScriptedTouchController):
    """Moves the TCP onto the candidate whose word the prompt's fact names, then holds still."""

    stateful = False

    def __init__(self, vocabulary: Sequence[str], field: str, prompt_template: PromptTemplate, key: str = "cube",
                 chunk_len: int = 8, gains: TouchGains | None = None):
        super().__init__(chunk_len=chunk_len, gains=gains)
        self.vocabulary, self.field, self.key = tuple(vocabulary), field, key
        self.spec = ControllerSpec(action_convention="pd_ee_delta_pose", chunk_len=chunk_len, action_dim=7,
                                   prompt_template=prompt_template)

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        words = [named_word(p, self.field) for p in parsed]
        if not any(w in self.vocabulary for w in words):
            return chunks
        extra = obs["extra"]
        tcp = as_numpy(extra["tcp_pose"]).astype(np.float64)
        targets = as_numpy(extra[f"{self.key}_positions"]).astype(np.float64)
        visible = as_numpy(extra[f"{self.key}_visible"]).astype(bool)
        velocity = tcp_velocity(as_numpy(obs["agent"]["qpos"]), as_numpy(obs["agent"]["qvel"]))
        for i, word in enumerate(words):
            if word not in self.vocabulary:
                continue  # no fact (or a word it was never trained on): hold still
            index = self.vocabulary.index(word)
            target = targets[i, index] if index < visible.shape[1] and visible[i, index] else None
            chunks[i] = self._chunk(tcp[i], velocity[i] * CONTROL_DT, target)
        return chunks


__all__ = ["TouchController", "named_word"]
