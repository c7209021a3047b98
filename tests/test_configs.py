"""The decision env's three configs and the flat env_kwargs a run saves them as."""

import dataclasses

import pytest

from sb3_memret.envs.configs import DecisionConfig, MemoryConfig, PhysicsConfig, split_env_kwargs
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.tasks.drawer import DrawerTask
from sb3_memret.tasks.drawer.household import HouseholdConfig


def test_flat_env_kwargs_split_into_the_task_and_three_configs():
    task, rest, memory, decisions, physics = split_env_kwargs({
        "capacity": 4, "long_term_capacity": 2, "memory_source": "observed", "retention": "fifo", "age_unit": "tasks",
        "location_decoys": 1, "k": 2, "mode": "oracle", "replan_every": 4, "gamma": 0.9, "tasks_per_episode": 3,
        "backend": "inprocess", "render_backend": "cpu", "objects": "heldout", "n_objects": 3,
        "move_probability": 0.5, "glimpses_per_episode": 1, "controller": "scripted"})
    assert memory == MemoryConfig(4, 2, "observed", "fifo", "tasks", SeedingConfig(location_decoys=1))
    assert memory.slots == 6
    assert decisions == DecisionConfig(mode="oracle", k=2, replan_every=4, gamma=0.9, tasks_per_episode=3)
    assert physics == PhysicsConfig(backend="inprocess", render_backend="cpu")
    assert isinstance(task, DrawerTask) and task.n_objects == 3 and len(task.objects) >= 3
    assert task.household == HouseholdConfig(move_probability=0.5, glimpses_per_episode=1)
    assert rest == {"controller": "scripted"}


def test_defaults_are_the_seed_drawer_and_configs_are_frozen():
    task, rest, memory, decisions, physics = split_env_kwargs({})
    assert task.name == "drawer" and task.objects == ("cube",) and rest == {}
    assert (memory, decisions, physics) == (MemoryConfig(), DecisionConfig(), PhysicsConfig())
    with pytest.raises(dataclasses.FrozenInstanceError):
        memory.capacity = 3


@pytest.mark.parametrize("kwargs, message", [
    ({"capacity": 0}, "capacity must be >= 1, got 0"),
    ({"long_term_capacity": 2}, "long-term store is written from what the robot sees"),
    ({"memory_source": "dreamt"}, "unknown memory source 'dreamt'"),
    ({"retention": "newest"}, "unknown retention rule 'newest'"),
    ({"age_unit": "days"}, "unknown age unit 'days'"),
    ({"mode": "psychic"}, "unknown mode 'psychic'"),
    ({"k": 0}, "k must be >= 1, got 0"),
    ({"replan_every": 0}, "replan_every must be >= 1 or None"),
    ({"gamma": 1.5}, r"gamma must be in \(0, 1\], got 1.5"),
    ({"backend": "tpu"}, "unknown physics backend 'tpu'"),
    ({"backend": "process", "ray_address": "auto"}, "needs the ray backend, not 'process'"),
    ({"render_backend": "vulkan"}, "unknown render backend 'vulkan'"),
    ({"n_objects": 5}, r"n_objects must be in \[1, 1\]"),
    ({"capacty": 6}, r"task 'drawer' has no option \['capacty'\]; its options are \['objects'"),
])
def test_a_bad_value_is_refused_naming_it(kwargs, message):
    with pytest.raises(ValueError, match=message):
        split_env_kwargs(kwargs)


def test_a_task_without_options_refuses_the_drawers():
    with pytest.raises(ValueError, match=r"task 'RememberColor3-VLA-v0' has no option \['objects'\]; its options are "
                                         "none"):
        split_env_kwargs({"task": "RememberColor3-VLA-v0", "objects": "heldout"})
