import numpy as np
import pytest

from sb3_memret.tasks.rewards import PHI_MAX, absorbing_success_value, shaped_reward, staged_potential

ORIGIN = np.zeros((1, 3))


def phi(distance, grasped=False, clear=False, success=False):
    return float(staged_potential(ORIGIN, np.array([[distance, 0, 0]]), [grasped], [clear], [success])[0])


def test_reach_term_is_one_at_contact_and_decays():
    assert phi(0.0) == pytest.approx(1.0)
    assert phi(0.2) == pytest.approx(1 - np.tanh(1.0))
    assert phi(0.05) > phi(0.1) > phi(0.5) > 0


def test_stages_are_ordered_and_success_is_max():
    reach, grasp, clear, done = phi(0.0), phi(0.0, grasped=True), phi(0.0, grasped=True, clear=True), phi(1.0, success=True)
    assert reach <= 1.0 < 2.0 <= grasp <= 3.0 < 4.0 <= clear <= 5.0 < done == PHI_MAX
    # any grasped state beats any reaching state, whatever the distance
    assert phi(1.0, grasped=True) > phi(0.0)


def test_potential_is_batched():
    eef = np.zeros((4, 3))
    cube = np.tile([[0.1, 0, 0]], (4, 1))
    out = staged_potential(eef, cube, [0, 1, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1])
    assert out.shape == (4,)
    assert np.all(np.diff(out) > 0)


def test_shaping_is_potential_difference():
    assert shaped_reward(np.array([1.0]), np.array([2.0]), 0.97)[0] == pytest.approx(0.97 * 2 - 1)
    # a closed loop of states earns (gamma-discounted) nothing extra when gamma = 1
    path = np.array([0.1, 2.5, 4.2, 0.1])
    assert shaped_reward(path[:-1], path[1:], 1.0).sum() == pytest.approx(0.0)


def test_bad_gamma_is_refused():
    with pytest.raises(ValueError, match="gamma"):
        shaped_reward(np.zeros(1), np.zeros(1), 1.5)


def _decision_returns_of_held_success(reward, remaining, left_now, per_decision, gamma):
    """The env run on after success, decision by decision: (1 - gamma) * the steps' reward, discounted per decision."""
    steps = [min(remaining, left_now)]
    remaining -= steps[0]
    while remaining > 0:
        steps.append(min(remaining, per_decision))
        remaining -= steps[-1]
    return sum(gamma ** j * (1.0 - gamma) * reward * n for j, n in enumerate(steps))


@pytest.mark.parametrize("remaining,left_now,per_decision", [(0, 3, 4), (3, 3, 4), (10, 0, 4), (11, 2, 4),
                                                             (376, 5, 24), (7, 7, 1)])
def test_an_absorbing_success_is_worth_the_cut_off_steps_decision_by_decision(remaining, left_now, per_decision):
    expected = _decision_returns_of_held_success(1.0, remaining, left_now, per_decision, 0.97)
    assert absorbing_success_value(1.0, remaining, left_now, per_decision, 0.97) == pytest.approx(expected)


def test_an_absorbing_success_outweighs_failing_slowly_and_checks_its_input():
    # an early success is worth more than a late one, and both more than nothing
    early, late = (absorbing_success_value(1.0, n, 0, 24, 0.97) for n in (300, 100))
    assert early > late > 0.0 == absorbing_success_value(1.0, 0, 0, 24, 0.97)
    with pytest.raises(ValueError, match="gamma must be in \\(0, 1\\], got 0.0"):
        absorbing_success_value(1.0, 4, 0, 4, 0.0)
    with pytest.raises(ValueError, match="remaining_steps=-1"):
        absorbing_success_value(1.0, -1, 0, 4, 0.97)
