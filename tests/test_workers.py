"""Stop signals around file writes, and the trainer's torch threads around a controller call."""

import os
import signal

import pytest
import torch

from sb3_memret.common.workers import StopRequested, stop_signals_deferred, stop_signals_interrupt, torch_threads


def test_a_stop_during_a_deferred_block_is_raised_when_it_ends():
    """SIGTERM while a checkpoint is written must not cut the file short: it waits for the block's end."""
    written, before = [], signal.getsignal(signal.SIGINT)
    with stop_signals_interrupt(), pytest.raises(StopRequested, match="SIGTERM"):
        with stop_signals_deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            written.append("the whole file")
    assert written == ["the whole file"]
    with pytest.raises(KeyboardInterrupt):
        with stop_signals_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            written.append("again")
    assert written[-1] == "again"
    assert signal.getsignal(signal.SIGINT) is before  # handlers are restored (SIG_IGN under nohup)


def test_torch_threads_are_restored():
    before = torch.get_num_threads()
    with torch_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with torch_threads(None):
        assert torch.get_num_threads() == before


def test_a_pool_whose_worker_is_killed_is_replaced_and_plays_only_what_had_not_landed(tmp_path, capsys):
    from sb3_memret.common.workers import replaying_pool
    from dying_worker import set_up, square_or_die

    jobs = [1, 2, -3, 4, 5]
    landed = list(replaying_pool(square_or_die, jobs, 2, set_up, (str(tmp_path),), replacements=1, what="episodes"))
    assert sorted(landed) == sorted((job, job ** 2) for job in jobs)  # each job exactly once
    err = capsys.readouterr().err
    assert "a worker died (pid " in err and "killed by SIGKILL" in err and "a new pool plays the" in err


def test_a_worker_that_keeps_dying_ends_the_pool_with_how_and_how_to_resume(tmp_path):
    from sb3_memret.common.workers import WorkerDiedError, replaying_pool
    from dying_worker import set_up, square_or_die

    (tmp_path / "always").touch()
    with pytest.raises(WorkerDiedError, match=r"killed by SIGKILL.*2 times in all; 1 episodes not played: run the "
                                              r"same command again to resume"):
        list(replaying_pool(square_or_die, [-1], 1, set_up, (str(tmp_path),), replacements=1, what="episodes"))
