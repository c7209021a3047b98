"""The finetune's batch sampler: uniform draws as before, draws by error favour the frames the policy gets wrong."""

import numpy as np
import pytest

from sb3_memret.stage1.sampling import FrameSampler


def test_a_uniform_sampler_draws_what_a_plain_choice_over_the_split_draws():
    frames = np.flatnonzero(np.arange(100) % 3 != 0)
    sampler = FrameSampler(frames)
    ours, plain = np.random.default_rng(4), np.random.default_rng(4)
    for _ in range(5):
        assert np.array_equal(sampler.draw(ours, 16), plain.choice(frames, size=16, replace=False))
    assert len(sampler.draw(ours, 1000)) == len(frames)  # a batch larger than the split takes all of it once


def test_frames_not_drawn_yet_count_as_the_worst_and_the_wrong_ones_come_more_often():
    frames = np.arange(0, 200, 2)
    sampler = FrameSampler(frames, priority=1.0)
    assert np.allclose(sampler.probabilities(), 1 / len(frames))
    sampler.update(frames[:50], np.r_[np.full(49, 0.1), 0.5])
    p = sampler.probabilities()
    assert np.allclose(p[50:], p[49]) and p[50] > p[0]  # unseen frames count as the largest error seen
    sampler.update(frames, np.r_[np.full(95, 0.1), np.full(5, 2.0)])
    p = sampler.probabilities()
    hard, easy = p[-5:], p[:-5]
    assert np.allclose(easy, easy[0]) and np.allclose(hard, hard[0])
    mean = (95 * 0.1 + 5 * 2.0) / 100
    assert hard[0] / easy[0] == pytest.approx((2.0 + mean) / (0.1 + mean))
    assert easy[0] * len(frames) > 0.45  # an easy frame is still drawn about half as often as an average one
    drawn = np.concatenate([sampler.draw(np.random.default_rng(s), 10) for s in range(400)])
    assert np.isin(drawn, frames[-5:]).mean() > 3 * 5 / 100
    assert len(set(sampler.draw(np.random.default_rng(0), 50))) == 50


def test_a_stronger_priority_favours_the_wrong_frames_more():
    frames = np.arange(10)
    shares = []
    for priority in (0.5, 1.0, 2.0):
        sampler = FrameSampler(frames, priority)
        sampler.update(frames, np.r_[np.full(9, 0.1), 1.0])
        shares.append(sampler.probabilities()[-1])
    assert shares[0] < shares[1] < shares[2]
    sampler = FrameSampler(frames, priority=8.0)  # one frame holds almost all the weight: the rest are topped up
    sampler.update(frames, np.r_[np.full(9, 0.01), 100.0])
    batch = sampler.draw(np.random.default_rng(1), 9)
    assert len(set(batch)) == 9 and 9 in batch


def test_the_errors_round_trip_and_bad_input_is_refused():
    frames = np.array([3, 5, 9])
    sampler = FrameSampler(frames, priority=1.0)
    sampler.update(np.array([9, 3]), np.array([0.5, 0.2]))
    restored = FrameSampler(frames, priority=1.0)
    restored.load_state(sampler.state())
    assert np.allclose(restored.probabilities(), sampler.probabilities())
    with pytest.raises(ValueError, match="2 training frames, this split has 3"):
        restored.load_state(np.zeros(2))
    with pytest.raises(ValueError, match="outside the training split"):
        sampler.update(np.array([4]), np.array([0.1]))
    with pytest.raises(ValueError, match="1 frames but 2 errors"):
        sampler.update(np.array([5]), np.array([0.1, 0.2]))
    with pytest.raises(ValueError, match="priority must be >= 0"):
        FrameSampler(frames, priority=-1.0)
    with pytest.raises(ValueError, match="at least one training frame"):
        FrameSampler(np.array([], dtype=int))


def test_strata_keep_their_share_of_the_draws_and_rank_frames_within_themselves():
    frames = np.arange(100)
    strata = np.r_[np.zeros(80, int), np.ones(20, int)]  # a task of 80 frames, one of 20
    sampler = FrameSampler(frames[::-1], priority=3.0, strata=strata[::-1])  # labels follow their frames
    assert np.allclose(sampler.probabilities(), 1 / 100)
    errors = np.r_[np.full(40, 1.0), np.full(40, 0.1), np.full(19, 0.1), 0.3]  # the first task is far harder
    sampler.update(frames, errors)
    p = sampler.probabilities()
    assert p[:80].sum() == pytest.approx(0.8) and p[80:].sum() == pytest.approx(0.2)  # each task keeps its share
    assert p[0] > p[79] and p[99] > p[80]  # within a task, its wrong frames come more often
    mean = (19 * 0.1 + 0.3) / 20  # the stratum's own mean error
    assert p[99] / p[80] == pytest.approx(((0.3 + mean) / (0.1 + mean)) ** 3)
    unstratified = FrameSampler(frames, priority=3.0)
    unstratified.update(frames, errors)
    assert unstratified.probabilities()[80:].sum() < 0.05  # without strata the hard task takes nearly every draw
    restored = FrameSampler(frames, priority=3.0, strata=strata)
    restored.load_state(sampler.state())
    assert np.allclose(restored.probabilities(), p)
    with pytest.raises(ValueError, match="99 strata labels for 100 frames"):
        FrameSampler(frames, priority=1.0, strata=strata[1:])
