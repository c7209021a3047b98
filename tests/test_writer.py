"""The rule-based writer, on hand-made predicates and on the real simulator."""

import numpy as np
import pytest
import torch
from mani_skill.utils.structs.pose import Pose

from sb3_memret.tasks.base import EnvFrame
from sb3_memret.common.obs_trees import to_numpy
from sb3_memret.memory.schema import MemoryType
from sb3_memret.memory.writer import UNKNOWN, EventCompiler
from sb3_memret.tasks.drawer import DrawerTask
from sb3_memret.tasks.drawer.writer import RELATIONS, BoundingBoxPredicateExtractor, ViewPredicateExtractor


class FakeEncoder:
    def __init__(self):
        self.calls = []

    def encode(self, texts):
        self.calls.append(list(texts))
        return np.ones((len(texts), 384), dtype=np.float32)


def test_compiler_emits_only_on_change():
    encoder = FakeEncoder()
    compiler = EventCompiler(encoder, RELATIONS)
    preds = {("location", "cube"): "drawer layer 2", ("holding", "robot"): "nothing"}
    first = compiler.update(preds, 0)
    assert [e.text for e in first] == ["the cube is in drawer layer 2.", "the robot is holding nothing."]
    assert all(e.embedding is not None and e.usage_count == 0 and e.importance > 0 for e in first)
    assert compiler.update(dict(preds), 8) == []
    assert compiler.update(dict(preds), 16) == []
    changed = compiler.update({**preds, ("holding", "robot"): "cube"}, 24)
    assert len(changed) == 1 and changed[0].text == "the robot is holding the cube." and changed[0].timestamp == 24
    assert changed[0].key == (MemoryType.HOLDING, "robot", "holding")
    assert encoder.calls == [[e.text for e in first], [changed[0].text]]  # batched, nothing re-encoded
    compiler.reset()
    assert len(compiler.update(preds, 0)) == 2


def test_unknown_values_are_not_written_and_bad_relations_refused():
    compiler = EventCompiler(None, RELATIONS)
    assert compiler.update({("location", "cube"): "unknown"}, 0) == []
    with pytest.raises(ValueError, match="unknown predicate relation 'colour'"):
        compiler.update({("colour", "cube"): "red"}, 0)


@pytest.mark.parametrize("layer", [1, 2, 3])
def test_extractor_names_the_right_layer_in_the_real_sim(task_env, layer):
    task_env.reset(seed=layer, options={"target_layer": layer})
    task_env.step(np.zeros(7, dtype=np.float32))
    preds = BoundingBoxPredicateExtractor().extract(task_env.unwrapped.privileged_state())
    assert preds == {("location", "cube"): f"drawer layer {layer}", ("holding", "robot"): "nothing"}


def test_extractor_changes_when_cube_is_lifted_out(task_env):
    task_env.reset(seed=0, options={"target_layer": 2})
    base = task_env.unwrapped
    extractor, compiler = BoundingBoxPredicateExtractor(), EventCompiler(None, RELATIONS, DrawerTask.wordings)
    compiler.update(extractor.extract(base.privileged_state()), 0)
    base.objects[0].set_pose(Pose.create_from_pq(torch.tensor([[base.layout.front_x - 0.2, 0.0, 0.5]])))
    entries = compiler.update(extractor.extract(base.privileged_state()), 8)
    assert [e.text for e in entries] == ["the cube is out of the drawers."]


def test_look_in_sees_each_placed_object_once_in_its_drawer(objects_env):
    base = objects_env.unwrapped
    for seed in range(5):
        obs, _ = objects_env.reset(seed=seed)
        state = base.privileged_state()
        views = base.look_in()[0]
        assert views.shape == (3, 4, 8)
        seen = ViewPredicateExtractor.look_in(views, state.object_names[0])
        assert seen == {("location", name): f"drawer layer {layer}" for name, layer in state.placed().items()}
        assert np.all(views[:, state.object_layer[0] == 0] == 0)  # objects the episode left out are never seen
        np.testing.assert_allclose(base.cabinet.get_qpos().numpy(), 0.0)  # looking in moved nothing
        assert np.all(obs["extra"]["target_detection"].numpy() == 0)  # and the episode starts blind
        glimpse = ViewPredicateExtractor.look_in(views[[2]], state.object_names[0], layers=[3])
        assert glimpse == {key: value for key, value in seen.items() if value == "drawer layer 3"}
        with pytest.raises(ValueError, match=r"3 views for the drawers \[3\]"):
            ViewPredicateExtractor.look_in(views, state.object_names[0], layers=[3])


def test_view_extractor_writes_a_location_only_while_the_target_is_seen(objects_env):
    objects_env.reset(seed=2, options={"target": "brick", "target_layer": 2})
    base, extractor = objects_env.unwrapped, ViewPredicateExtractor()

    def read():
        obs, state = to_numpy(base.get_obs(base.evaluate())), base.privileged_state()
        return extractor.extract(EnvFrame(obs, state, 0.0, False, views=base.views(state)[0]))

    assert read() == {("location", "brick"): UNKNOWN, ("holding", "robot"): "nothing"}  # all closed: nothing seen
    base.cabinet.set_qpos(torch.tensor([[0.0, 0.28, 0.0]]))
    low, high = base.layout.inner_box(2, 0.28)
    base.objects[base.object_names.index("brick")].set_pose(
        Pose.create_from_pq(torch.as_tensor(((low + high) / 2)[None], dtype=torch.float32)))
    assert read()[("location", "brick")] == "drawer layer 2"  # seen in the open drawer
    base.objects[base.object_names.index("brick")].set_pose(
        Pose.create_from_pq(torch.tensor([[base.layout.front_x - 0.2, 0.0, 0.5]])))
    assert read()[("location", "brick")] == "outside"
