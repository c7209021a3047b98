"""Worker processes and stop signals: who handles Ctrl-C and SIGTERM, what a dead worker says, and a plain map of
any work over spawned worker processes (``map_in_workers``: the demonstrations use it).

Ctrl-C (SIGINT) and a scheduler's SIGTERM reach the whole process group. Only the parent acts
on them: it saves a checkpoint and then closes its workers, which therefore ignore both.
"""

from __future__ import annotations

import multiprocessing
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from multiprocessing.process import BaseProcess
from typing import Callable, Iterator, Sequence, TypeVar

J = TypeVar("J")
R = TypeVar("R")

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
# Workers are the parent's own children. Under "forkserver" they are the children of a server
# process that a SIGTERM to the group kills, after which the parent can no longer tell whether
# they are alive ("fork" is unsafe with the threads torch and SAPIEN start).
START_METHOD = "spawn"


class StopRequested(KeyboardInterrupt):
    """A stop signal arrived; handled like Ctrl-C (checkpoint, clean shutdown, resume hint)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signal_name = signal.Signals(signum).name


class WorkerDiedError(RuntimeError):
    """A worker process ended while the parent still needed it (killed, out of memory, crashed)."""


def init_worker_process(ignored: tuple[signal.Signals, ...] = STOP_SIGNALS) -> None:
    """Make this process a quiet worker: the ``ignored`` stop signals are the parent's, and one
    torch thread each keeps n workers from oversubscribing the cores."""
    import torch

    for signum in ignored:
        signal.signal(signum, signal.SIG_IGN)
    torch.set_num_threads(1)


@contextmanager
def stop_signals_interrupt() -> Iterator[None]:
    """Within, SIGTERM raises ``StopRequested`` in the main thread as Ctrl-C raises KeyboardInterrupt.

    Outside the main thread (where Python cannot install handlers) it changes nothing.
    """

    def handler(signum: int, frame: object) -> None:
        raise StopRequested(signum)

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Within, torch computes with ``n`` intra-op threads (None: unchanged).

    A controller acting in the trainer while physics workers share the machine's cores should use
    one: idle intra-op threads spin-wait after every op and take those cores from the workers
    (measured here: 21 ms of trainer CPU per decision with two threads, 6 ms with one).
    """
    import torch

    previous = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


@contextmanager
def stop_signals_deferred() -> Iterator[None]:
    """Within, Ctrl-C and SIGTERM wait: they are raised (KeyboardInterrupt, ``StopRequested``) when the
    block ends, so a file being written (a checkpoint) is never cut off half-way by the stop it serves.

    Outside the main thread (where Python cannot install handlers) it changes nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    previous = {signum: signal.signal(signum, lambda signum, frame: pending.append(signum)) for signum in STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    if pending:
        if pending[0] == signal.SIGINT:
            raise KeyboardInterrupt
        raise StopRequested(pending[0])


def exit_status(stopped_by: str) -> int:
    """The shell's convention for a run stopped early: 128 + the signal's number for Ctrl-C and
    SIGTERM, 1 for anything else (a dead worker)."""
    signum = {"Ctrl-C": signal.SIGINT, "SIGTERM": signal.SIGTERM}.get(stopped_by)
    return 128 + signum if signum is not None else 1


def exit_description(process: BaseProcess, timeout: float = 1.0) -> str:
    """How a worker process ended, e.g. 'killed by SIGKILL' or 'exited with code 1'."""
    deadline = time.monotonic() + timeout
    process.join(timeout=timeout)
    # the executor's own thread may be reaping the same process this moment: its exit code lands a little later
    while process.exitcode is None and time.monotonic() < deadline:
        time.sleep(0.01)
    code = process.exitcode
    if code is None:
        return "stopped answering (still running)"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exited with code {code}"


def init_pool_worker() -> None:
    """Set up a pool worker process: SIGINT ignored (the parent handles it), SIGTERM left fatal, since a
    broken ProcessPoolExecutor ends its remaining workers with it."""
    init_worker_process(ignored=(signal.SIGINT,))


def map_in_workers(
    initializer: Callable[..., None],
    initargs: tuple,
    work: Callable[[J], R],
    jobs: Sequence[J],
    n_workers: int = 1,
    on_result: Callable[[J, R], None] | None = None,
) -> list[R]:
    """``[work(job) for job in jobs]`` after ``initializer(*initargs)``: in this process when ``n_workers``
    is 1, else in that many spawned worker processes; results in job order, ``on_result`` as each arrives."""
    if n_workers < 1:
        raise ValueError(f"n_workers must be >= 1, got {n_workers}")
    if not jobs:
        return []
    if n_workers == 1:
        initializer(*initargs, in_worker=False)
        results_here = []
        for job in jobs:
            results_here.append(work(job))
            if on_result is not None:
                on_result(job, results_here[-1])
        return results_here
    results: list[R | None] = [None] * len(jobs)
    context = multiprocessing.get_context(START_METHOD)
    with ProcessPoolExecutor(min(n_workers, len(jobs)), mp_context=context, initializer=initializer,
                             initargs=initargs) as pool:
        pending: dict[Future, int] = {pool.submit(work, job): i for i, job in enumerate(jobs)}
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    i = pending.pop(future)
                    results[i] = future.result()
                    if on_result is not None:
                        on_result(jobs[i], results[i])
        except BrokenProcessPool as err:  # a worker was killed (out of memory, a signal)
            raise WorkerDiedError(f"a worker process died while playing: {err}") from err
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    return results  # type: ignore[return-value]


def replaying_pool(work: Callable[[J], R], jobs: Sequence[J], n_workers: int, initializer: Callable[..., None],
                   initargs: tuple, replacements: int, what: str = "jobs") -> Iterator[tuple[J, R]]:
    """``(job, work(job))`` as each lands, from ``n_workers`` spawned processes set up by ``initializer(*initargs)``.

    A worker that dies (killed, out of memory) breaks its pool: a new pool replaces it and plays the jobs that had not
    landed, up to ``replacements`` times; after that a ``WorkerDiedError`` says how the workers ended and that running
    the same command again resumes. A landed job is never played again. The pool is shut down at once when the
    caller stops early (Ctrl-C, SIGTERM): the jobs under way are ended, not waited for.
    """
    left, deaths = list(jobs), 0
    context = multiprocessing.get_context(START_METHOD)
    while left:
        pool = ProcessPoolExecutor(n_workers, mp_context=context, initializer=initializer, initargs=initargs)
        seen: dict[int, BaseProcess] = {}
        try:
            pending: dict[Future, int] = {pool.submit(work, job): i for i, job in enumerate(left)}
            done_here: set[int] = set()
            try:
                while pending:
                    seen.update(_pool_processes(pool))
                    done, _ = wait(pending, return_when=FIRST_COMPLETED)
                    for future in done:
                        i = pending.pop(future)
                        result = future.result()
                        done_here.add(i)
                        yield left[i], result
            except BrokenProcessPool:
                seen.update(_pool_processes(pool))
                ended = {pid: exit_description(p) for pid, p in seen.items()}  # joins each, so its exit code is known
                how = "; ".join(f"pid {pid} {ended[pid]}" for pid, p in seen.items()
                                if p.exitcode not in (None, 0)) or "a worker process ended"
                left = [job for i, job in enumerate(left) if i not in done_here]
                deaths += 1
                if deaths > replacements:
                    raise WorkerDiedError(f"a worker died ({how}), {deaths} times in all; {len(left)} {what} not "
                                          "played: run the same command again to resume") from None
                print(f"a worker died ({how}): a new pool plays the {len(left)} {what} left", file=sys.stderr)
                continue
            left = []
        finally:
            for process in _pool_processes(pool).values():
                if process.is_alive():
                    process.terminate()
            pool.shutdown(wait=True, cancel_futures=True)


def _pool_processes(pool: ProcessPoolExecutor) -> dict[int, BaseProcess]:
    """The pool's worker processes by pid (the executor keeps them in ``_processes``; none once it has shut down)."""
    return dict(getattr(pool, "_processes", None) or {})


__all__ = ["START_METHOD", "STOP_SIGNALS", "StopRequested", "WorkerDiedError", "exit_description", "exit_status",
           "init_pool_worker", "init_worker_process", "map_in_workers", "replaying_pool", "stop_signals_deferred", "stop_signals_interrupt",
           "torch_threads"]
