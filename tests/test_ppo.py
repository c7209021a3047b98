"""MemRetPPO's own round: advantages scaled once per round, never by less than a fraction of the widest spread."""

import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_memret.policy.policy import MemoryRetrievalPolicy
from sb3_memret.policy.ppo import MemRetPPO
from toy_bank import ToyBankEnv


def scaled_rounds(model: MemRetPPO, rounds: list[np.ndarray], monkeypatch: pytest.MonkeyPatch) -> list[np.ndarray]:
    """The advantages SB3's update receives for each round of raw advantages given."""
    seen = []
    model.set_logger(configure(None, []))
    monkeypatch.setattr(PPO, "train", lambda self: seen.append(self.rollout_buffer.advantages.copy()))
    for advantages in rounds:
        model.rollout_buffer.advantages = advantages.copy()
        model.train()
    return seen


def test_a_round_of_noise_after_a_wide_round_is_not_blown_up_to_unit_spread(monkeypatch):
    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=8, batch_size=8, seed=0)
    rng = np.random.default_rng(0)
    wide, narrow, wider = (rng.normal(5.0, s, (8, 1)) for s in (2.0, 0.01, 3.0))
    seen = scaled_rounds(model, [wide, narrow, wider], monkeypatch)
    assert seen[0].mean() == pytest.approx(0.0, abs=1e-9) and seen[0].std() == pytest.approx(1.0)
    assert seen[1].mean() == pytest.approx(0.0, abs=1e-9)
    assert seen[1].std() == pytest.approx(narrow.std() / (0.25 * wide.std()))  # divided by the floor, not its own
    assert seen[2].std() == pytest.approx(1.0)  # a round wider than the floor is scaled to unit spread
    assert model.widest_advantage_std == pytest.approx(wider.std())


def test_floor_zero_scales_every_round_to_unit_spread(monkeypatch):
    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=8, batch_size=8, seed=0,
                      advantage_std_floor=0.0)
    rng = np.random.default_rng(1)
    seen = scaled_rounds(model, [rng.normal(0, 2.0, (8, 1)), rng.normal(0, 0.01, (8, 1))], monkeypatch)
    assert [s.std() for s in seen] == [pytest.approx(1.0), pytest.approx(1.0)]


def test_the_widest_spread_survives_save_and_load(tmp_path):
    model = MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), n_steps=16, batch_size=16, seed=0)
    model.learn(32)
    assert model.widest_advantage_std > 0
    model.save(tmp_path / "model.zip")
    loaded = MemRetPPO.load(tmp_path / "model.zip")
    assert loaded.widest_advantage_std == model.widest_advantage_std and loaded.advantage_std_floor == 0.25


@pytest.mark.parametrize("floor", [-0.1, 1.5])
def test_a_floor_outside_zero_to_one_is_refused(floor):
    with pytest.raises(ValueError, match=rf"advantage_std_floor must be in \[0, 1\].*got {floor}"):
        MemRetPPO(MemoryRetrievalPolicy, DummyVecEnv([ToyBankEnv]), advantage_std_floor=floor)
