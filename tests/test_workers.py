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
