"""A one-decision synthetic bank task that stands in for the simulator in fast tests."""

import gymnasium as gym
import numpy as np
from gymnasium import spaces

CAP, DIM = 6, 384


class ToyBankEnv(gym.Env):
    """The bank holds one 'true' memory near a fixed direction among random decoys; reward 1
    for retrieving it, and the episode 'succeeds' when it is retrieved. ``info`` carries the keys
    DrawerRecall-v0 reports, so evaluation and callbacks run on it unchanged."""

    def __init__(self, empty_slots: int = 0, potential: bool = False):
        self.empty_slots, self.potential = empty_slots, potential
        self.observation_space = spaces.Dict(
            instruction=spaces.Box(-1, 1, (DIM,), np.float32), memories=spaces.Box(-1, 1, (CAP, DIM), np.float32),
            mask=spaces.Box(0, 1, (CAP,), np.float32), type_ids=spaces.Box(0, 5, (CAP,), np.float32),
            age=spaces.Box(0, np.inf, (CAP,), np.float32), usage=spaces.Box(0, np.inf, (CAP,), np.float32),
            **({"potential": spaces.Box(0, np.inf, (1,), np.float32)} if potential else {}))
        self.action_space = spaces.MultiDiscrete([CAP])
        direction = np.random.default_rng(123).standard_normal(DIM)
        self.direction = (direction / np.linalg.norm(direction)).astype(np.float32)
        self.received_weights = []

    def set_retention_weights(self, state_dict, age_unit):
        self.received_weights.append(state_dict)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        n = CAP - self.empty_slots
        mem = self.np_random.standard_normal((CAP, DIM)).astype(np.float32)
        self.true = int(self.np_random.integers(n))
        self.layer = int(self.np_random.integers(1, 4))
        mem[self.true] = self.direction + 0.3 * mem[self.true] / np.sqrt(DIM)
        mem /= np.linalg.norm(mem, axis=1, keepdims=True)
        mem[n:] = 0
        mask = (np.arange(CAP) < n).astype(np.float32)
        self.obs = dict(instruction=np.full(DIM, 1 / np.sqrt(DIM), np.float32), memories=mem, mask=mask,
                        type_ids=np.zeros(CAP, np.float32), age=np.zeros(CAP, np.float32), usage=np.zeros(CAP, np.float32))
        if self.potential:
            self.obs["potential"] = self.np_random.uniform(0.0, 0.2, (1,)).astype(np.float32)
        return self.obs, {"true_slot": self.true}

    def step(self, action):
        hit = int(action[0]) == self.true
        info = {"true_slot": self.true, "decision_true_slots": [self.true], "retrieved_true": hit, "success": hit,
                "group": str(self.layer), "true_evicted": False}
        return self.obs, float(hit), True, False, info
