"""The line between what the benchmark itself reads of the simulator and what the policy may read.

MIKASA's harness gives a policy its cameras, its proprioception and the instruction. The benchmark reads more for
itself: the episode's truth for the oracle and wrong conditions and for its metrics (``Task.frames``), the
instruction an env states per episode, and a privileged controller's detector (a row then labelled an upper bound).
Those reads happen inside ``benchmark_reads``. ``SimulatorGuard`` holds the harness env for the agent and refuses
every other read of it while the agent acts, so a writer, retriever or controller that touches the simulator fails
at once instead of lifting a row above what the protocol allows.
"""

from __future__ import annotations

import contextlib
import contextvars
from typing import Any, Iterator

_READER: contextvars.ContextVar[str | None] = contextvars.ContextVar("benchmark_reader", default=None)


class SimulatorRead(RuntimeError):
    """The policy side read the simulator while acting."""


@contextlib.contextmanager
def benchmark_reads(why: str) -> Iterator[None]:
    """The benchmark's own reads of the simulator (``why`` says which), allowed while the agent acts."""
    token = _READER.set(why)
    try:
        yield
    finally:
        _READER.reset(token)


class SimulatorGuard:
    """The harness env as the agent holds it: every attribute passes through, except that while ``acting`` a read
    outside ``benchmark_reads`` raises ``SimulatorRead`` naming it."""

    def __init__(self, env: Any):
        object.__setattr__(self, "_env", env)
        object.__setattr__(self, "acting", False)

    def __getattr__(self, name: str) -> Any:
        if self.acting and _READER.get() is None:
            raise SimulatorRead(f"the policy side read {name!r} of the harness env while acting: the writer, bank, "
                                "retriever and a protocol controller may read the harness's observation alone (rgb, "
                                "proprio, the instruction)")
        return getattr(self._env, name)

    def __setattr__(self, name: str, value: Any) -> None:
        if name != "acting":
            raise AttributeError(f"the agent does not set {name!r} on the harness env")
        object.__setattr__(self, name, value)

    @contextlib.contextmanager
    def armed(self) -> Iterator[None]:
        """Refuse the policy side's reads for the duration (one ``forward``)."""
        object.__setattr__(self, "acting", True)
        try:
            yield
        finally:
            object.__setattr__(self, "acting", False)


__all__ = ["SimulatorGuard", "SimulatorRead", "benchmark_reads"]
