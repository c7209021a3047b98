"""The Panda's ``is_grasping`` asked once per object and physics step on a CPU simulation.

MIKASA's BatteriesChecker asks it of each of its 15 batteries twice a control step (``evaluate`` and the dense
reward): 30 calls, two thirds of an episode's time on a CPU (``scripts/bench_grasp_memo.py``). The answer depends only
on the contacts of the last physics step and the fingers' poses, so within one step the memo answers the repeats.
It computes what ManiSkill's does, in the same operations: the fingers' opening directions and the contact list
once per state (the scene's physics-step count and the fingers' poses: contacts change only when the scene steps,
which every MIKASA env does through ``ManiSkillScene.step``), then each object's forces and angles, answered again
from the memo within the state; each caller gets its own copy. GPU simulation keeps ManiSkill's batched queries.
"""

from __future__ import annotations

from typing import Any

_STEPS = "_sb3_memret_physics_steps"
_MEMO = "_sb3_memret_grasp_memo"


def install_grasp_memo() -> None:
    """Count each ManiSkill scene's physics steps and answer ``Panda.is_grasping`` from one reading of the fingers
    and the contacts per physics step (idempotent)."""
    import torch
    from mani_skill.agents.robots.panda.panda import Panda
    from mani_skill.envs.scene import ManiSkillScene
    from mani_skill.utils import common, sapien_utils

    if getattr(ManiSkillScene.step, "_sb3_memret", False):
        return
    scene_step, is_grasping = ManiSkillScene.step, Panda.is_grasping

    def step(self: ManiSkillScene) -> None:
        setattr(self, _STEPS, getattr(self, _STEPS, 0) + 1)
        scene_step(self)

    def memoised(self: Panda, object: Any, min_force: float = 0.5, max_angle: float = 85) -> Any:
        scene = self.scene
        if scene.gpu_sim_enabled:
            return is_grasping(self, object, min_force, max_angle)
        poses = (self.finger1_link.pose, self.finger2_link.pose)
        state = (getattr(scene, _STEPS, 0), *(pose.raw_pose.numpy().tobytes() for pose in poses))
        held = getattr(scene, _MEMO, None)
        if held is None or held["state"] != state:  # what ManiSkill's is_grasping reads, read once for this state
            held = {"state": state, "contacts": scene.px.get_contacts(), "answers": {},
                    "directions": (poses[0].to_transformation_matrix()[..., :3, 1],
                                   -poses[1].to_transformation_matrix()[..., :3, 1])}
            setattr(scene, _MEMO, held)
        key = (id(object), float(min_force), float(max_angle))
        if key not in held["answers"]:
            forces = [common.to_tensor(sapien_utils.get_pairwise_contact_impulse(
                held["contacts"], finger._bodies[0].entity, object._bodies[0].entity))[None, :] / scene.px.timestep
                for finger in (self.finger1_link, self.finger2_link)]  # Scene.get_pairwise_contact_forces on a CPU
            flags = [torch.logical_and(torch.linalg.norm(force, axis=1) >= min_force,
                                       torch.rad2deg(common.compute_angle_between(direction, force)) <= max_angle)
                     for force, direction in zip(forces, held["directions"])]
            held["answers"][key] = (object, torch.logical_and(*flags))  # the object kept, so its id stays its own
        return held["answers"][key][1].clone()

    step._sb3_memret = True
    memoised.__wrapped__ = is_grasping  # ManiSkill's own, for comparison
    ManiSkillScene.step, Panda.is_grasping = step, memoised


__all__ = ["install_grasp_memo"]
