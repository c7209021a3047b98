"""DrawerCubeTakeOut-v1: take the named object (by default a cube) out of one of three stacked drawers
with a Franka Panda."""

from __future__ import annotations

from contextlib import contextmanager
from typing import Any, Iterator

import numpy as np
import sapien
import torch
from mani_skill.agents.robots.panda.panda import Panda
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.geometry.rotation_conversions import quaternion_to_axis_angle
from mani_skill.utils.registration import register_env
from mani_skill.utils.structs.pose import Pose

from sb3_memret.tasks.drawer.cabinet import LAYERS, CabinetLayout, build_cabinet, check_layer
from sb3_memret.tasks.drawer.objects import ObjectSpec, object_specs
from sb3_memret.tasks.drawer.robot import LIGHT_PANDA_UID
from sb3_memret.tasks.drawer.state import DrawerCubeState, layer_containing
from sb3_memret.tasks.rewards import staged_potential

PARK_X = -1.0  # objects an episode does not use wait on the floor behind the robot, out of its reach
GRASP_QUERY_RADIUS = 0.1  # m between TCP and target centre beyond which no grasp is possible
IMAGE_SIZE = 224
DEFAULT_ROBOT = LIGHT_PANDA_UID  # ManiSkill's Panda with its visual meshes decimated: same physics, pictures 3x cheaper


@register_env("DrawerCubeTakeOut-v1", max_episode_steps=400)
class DrawerCubeTakeOutEnv(BaseEnv):
    """
    **Task Description:**
    A Franka Panda faces a cabinet of three stacked drawers (layer 1 top, 2 middle, 3 bottom),
    each with a vertical bar handle graspable from the front. Objects lie inside the drawers, at
    most one per drawer; the instruction names one of them, the target, which the robot must
    open its drawer for and take out. Which drawer is not observable until it is open, so a
    policy has to be told (or remember) the layer. By default the only object is a cube (the
    seed's task); ``objects`` and ``n_objects`` hide several (``sb3_memret.tasks.drawer.objects``).

    **Randomizations:**

    - the target's layer is uniform over {1, 2, 3} (fix it with ``options={"target_layer": L}``)
    - which ``n_objects`` of ``objects`` the episode uses is uniform, and so is which of them is
      the target (fix it with ``options={"target": name}``); the others go to distinct other layers
      (or fix them all with ``options={"placement": {name: layer, ...}, "target": name}``)
    - each object's position in its drawer: 4-9 cm behind the inner front, ``|y| <= 8 cm``
    - each object's yaw is uniform in [-pi/6, pi/6]
    - the arm's joint positions get N(0, ``robot_init_qpos_noise``) noise around the rest pose
    - all drawers start closed; the cabinet itself never moves

    **Success Conditions:**

    - the target's centre is outside every drawer's interior box, and
    - it is raised above the cabinet top (``lift_height``) or pulled past the cabinet front
      (``front_margin`` in front of its face).

    **Observations:** ``agent/eef_state`` is the 8-D end-effector state (TCP position and
    axis-angle in the robot base frame, two gripper joints). ``extra/drawer_opening`` (3) is
    what a camera sees of the drawers; ``extra/target_detection`` (8: visible flag, position,
    wxyz quaternion) is the target as a camera with a detector prompted by the instruction's
    object word would see it: zeros while its drawer is closed. With a render backend,
    ``base_camera`` and ``hand_camera`` give 224x224 RGB images; inside ``sensors_paused()``
    steps return the state part only, so a controller that reads images once per action chunk
    pays for one render per chunk, not one per control step. The robot is ``panda_light`` by default:
    ManiSkill's Panda with visual meshes a tenth as dense (``sb3_memret.tasks.drawer.robot``: pictures three
    times cheaper on a CPU, the same physics); ``robot_uids="panda"`` draws ManiSkill's own. A camera
    controller must be trained on the robot it sees.

    **Action:** 7-D ``pd_ee_delta_pose`` (3 translation, 3 rotation, gripper), sent unmodified.
    """

    SUPPORTED_ROBOTS = [LIGHT_PANDA_UID, "panda"]
    agent: Panda

    def __init__(
        self,
        *args: Any,
        robot_uids: str = DEFAULT_ROBOT,
        robot_init_qpos_noise: float = 0.02,
        layout: CabinetLayout | None = None,
        visible_opening: float = 0.15,
        lift_height: float | None = None,
        front_margin: float = 0.05,
        objects: tuple[str, ...] = ("cube",),
        n_objects: int = 1,
        **kwargs: Any,
    ):
        kwargs.setdefault("control_mode", "pd_ee_delta_pose")
        if kwargs.get("render_backend") in ("cpu", "sapien_cpu"):
            from sb3_memret.common.rendering import use_cpu_renderer

            use_cpu_renderer()  # however the env is made (gymnasium, the toolkit, a worker); refuses naming `make renderer`
        self.layout = layout or CabinetLayout()
        self.object_specs: tuple[ObjectSpec, ...] = object_specs(objects)
        if not 1 <= n_objects <= min(len(self.object_specs), len(LAYERS)):
            raise ValueError(f"n_objects must be in [1, {min(len(self.object_specs), len(LAYERS))}] for objects "
                             f"{list(objects)!r} and {len(LAYERS)} drawers, got {n_objects}")
        self.n_objects = n_objects
        self.robot_init_qpos_noise = robot_init_qpos_noise
        self.visible_opening = visible_opening
        self.lift_height = self.layout.top_z + 0.02 if lift_height is None else lift_height
        self.front_margin = front_margin
        self._object_layer_np: np.ndarray | None = None  # (B, M) placed layer per object, 0 = unused
        self._target_index_np: np.ndarray | None = None  # (B,)
        self._sensors_paused = False
        # (3, 2, 3): each layer's interior (low, high) with every drawer closed
        self._closed_boxes = np.stack([np.stack(self.layout.inner_box(layer)) for layer in LAYERS])
        super().__init__(*args, robot_uids=robot_uids, **kwargs)

    # ------------------------------------------------------------------ scene
    @property
    def _default_sensor_configs(self) -> list[CameraConfig]:
        base_pose = sapien_utils.look_at(eye=[0.15, 0.45, 0.75], target=[0.65, 0.0, 0.3])
        wrist_pose = sapien.Pose(p=[0.05, 0.0, 0.02], q=[0.70710678, 0.0, -0.70710678, 0.0])
        return [
            CameraConfig("base_camera", base_pose, IMAGE_SIZE, IMAGE_SIZE, np.pi / 2, 0.01, 100),
            CameraConfig("hand_camera", wrist_pose, IMAGE_SIZE, IMAGE_SIZE, np.pi / 2, 0.01, 100,
                         mount=self.agent.robot.links_map["panda_hand"]),
        ]

    @property
    def _default_human_render_camera_configs(self) -> CameraConfig:
        pose = sapien_utils.look_at([0.0, 1.0, 0.9], [0.6, 0.0, 0.3])
        return CameraConfig("render_camera", pose, 512, 512, 1.0, 0.01, 100)

    def _load_agent(self, options: dict) -> None:
        super()._load_agent(options, sapien.Pose(p=[0.0, 0.0, 0.0]))

    def _load_scene(self, options: dict) -> None:
        render = self.scene.can_render()
        ground = self.scene.create_actor_builder()
        ground.add_plane_collision(sapien.Pose(q=[0.7071068, 0.0, -0.7071068, 0.0]))
        if render:
            ground.add_box_visual(sapien.Pose(p=[0, 0, -0.005]), half_size=[3, 3, 0.005],
                                  material=sapien.render.RenderMaterial(base_color=[0.8, 0.8, 0.8, 1]))
        ground.initial_pose = sapien.Pose()
        self.ground = ground.build_static(name="ground")
        self.cabinet = build_cabinet(self.scene, self.layout)
        self.drawer_links = [self.cabinet.links_map[f"drawer_{layer}"] for layer in LAYERS]

        self.objects = [self._build_object(spec, render) for spec in self.object_specs]

    def _build_object(self, spec: ObjectSpec, render: bool):
        builder = self.scene.create_actor_builder()
        builder.add_box_collision(half_size=list(spec.half_size))
        if render:
            builder.add_box_visual(half_size=list(spec.half_size),
                                   material=sapien.render.RenderMaterial(base_color=[*spec.color, 1]))
        builder.initial_pose = sapien.Pose(p=[0.0, 0.0, 2.0])
        return builder.build(name=spec.name)

    @property
    def object_names(self) -> tuple[str, ...]:
        return tuple(spec.name for spec in self.object_specs)

    # ---------------------------------------------------------- episode init
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        b = len(env_idx)
        with torch.device(self.device):
            rest = torch.as_tensor(self.agent.keyframes["rest"].qpos, dtype=torch.float32)
            qpos = rest.repeat(b, 1)
            qpos[:, :7] += torch.randn(b, 7) * self.robot_init_qpos_noise
            self.agent.reset(qpos)
            self.agent.robot.set_pose(sapien.Pose())
            self.cabinet.set_qpos(torch.zeros(b, len(LAYERS)))
            self.cabinet.set_qvel(torch.zeros(b, len(LAYERS)))

            if "placement" in options:
                chosen, layers = self._placed_as(b, options["placement"], options.get("target"))
            else:
                target_layer = options.get("target_layer")
                if target_layer is None:
                    target_layers = torch.randint(1, len(LAYERS) + 1, (b,))
                else:
                    target_layers = torch.full((b,), check_layer(target_layer), dtype=torch.long)
                chosen = self._draw_objects(b, options.get("target"))
                layers = self._draw_other_layers(target_layers)
            ids = env_idx.cpu().numpy()
            if self._object_layer_np is None:
                self._object_layer_np = np.zeros((self.num_envs, len(self.object_specs)), dtype=np.int64)
                self._target_index_np = np.zeros(self.num_envs, dtype=np.int64)
            self._object_layer_np[ids] = 0
            rows = np.arange(b)
            for column in range(self.n_objects):
                self._object_layer_np[ids, chosen[:, column].cpu().numpy()] = layers[:, column].cpu().numpy()
            self._target_index_np[ids] = chosen[:, 0].cpu().numpy()

            half = torch.as_tensor([spec.half_size for spec in self.object_specs], dtype=torch.float32)
            poses = [self._parked(j, b) for j in range(len(self.object_specs))]
            for column in range(self.n_objects):
                lows = torch.as_tensor(np.stack([self.layout.inner_box(int(l))[0] for l in layers[:, column]]),
                                       dtype=torch.float32)
                size = half[chosen[:, column]]
                pos = lows.clone()
                pos[:, 0] += size[:, 0] + 0.04 + 0.05 * torch.rand(b)
                pos[:, 1] = (torch.rand(b) * 2 - 1) * 0.08
                pos[:, 2] += size[:, 2] + 1e-3
                yaw = (torch.rand(b) * 2 - 1) * (np.pi / 6)
                quat = torch.stack([torch.cos(yaw / 2), torch.zeros(b), torch.zeros(b), torch.sin(yaw / 2)], dim=1)
                for i, j in zip(rows, chosen[:, column].tolist()):
                    poses[j][0][i], poses[j][1][i] = pos[i], quat[i]
            for actor, (pos, quat) in zip(self.objects, poses):
                actor.set_pose(Pose.create_from_pq(pos, quat))

    def _placed_as(self, b: int, placement: dict[str, int], target: str | None) -> tuple[torch.Tensor, torch.Tensor]:
        """(b, n_objects) object indices and layers of a given ``placement`` (name -> layer), the target first."""
        names = list(placement)
        if len(names) != self.n_objects or set(names) - set(self.object_names) or \
                len({check_layer(layer) for layer in placement.values()}) != len(names):
            raise ValueError(f"placement must put {self.n_objects} of the objects {list(self.object_names)} in distinct "
                             f"drawer layers, got {placement!r}")
        if target is None or target not in placement:
            raise ValueError(f"a placement needs a target among its objects {names}, got {target!r}")
        names.remove(target)
        order = [target, *names]
        chosen = torch.as_tensor([self.object_names.index(n) for n in order]).repeat(b, 1)
        return chosen, torch.as_tensor([placement[n] for n in order]).repeat(b, 1)

    def _draw_objects(self, b: int, target: str | None) -> torch.Tensor:
        """(b, n_objects) indices of the episode's objects, the target first."""
        m = len(self.object_specs)
        if target is not None and target not in self.object_names:
            raise ValueError(f"target {target!r} is not one of this task's objects {list(self.object_names)}")
        if m == 1:
            return torch.zeros((b, 1), dtype=torch.long)
        keys = torch.rand(b, m)
        if target is not None:
            keys[:, self.object_names.index(target)] = -1.0
        return keys.argsort(dim=1)[:, : self.n_objects]

    def _draw_other_layers(self, target_layers: torch.Tensor) -> torch.Tensor:
        """(b, n_objects) layers: the target's first, then distinct other layers in random order."""
        if self.n_objects == 1:
            return target_layers[:, None]
        keys = torch.rand(len(target_layers), len(LAYERS))
        keys[torch.arange(len(target_layers)), target_layers - 1] = -1.0
        return keys.argsort(dim=1)[:, : self.n_objects] + 1

    def _parked(self, j: int, b: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Object ``j`` resting on the floor behind the robot, where an episode that leaves it out keeps it."""
        pos = torch.tensor([PARK_X, -0.3 + 0.12 * j, self.object_specs[j].half_size[2] + 1e-3]).repeat(b, 1)
        return pos, torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(b, 1)

    # ------------------------------------------------------------ evaluation
    def privileged_state(self) -> DrawerCubeState:
        """Simulator truth for the memory writer and the reward; never for a controller."""
        qpos = self.cabinet.get_qpos().cpu().numpy().astype(np.float64)
        shift = np.zeros((*qpos.shape, 1, 3))
        shift[..., 0, 0] = -qpos  # drawers slide towards the robot along -x
        boxes = self._closed_boxes + shift
        tcp = self.agent.tcp.pose.raw_pose.cpu().numpy().astype(np.float64)
        poses = np.stack([actor.pose.raw_pose.cpu().numpy().astype(np.float64) for actor in self.objects], axis=1)
        envs = np.arange(len(tcp))
        target = poses[envs, self._target_index_np]
        # Contact queries are the slow part of a CPU step: only ask when the target is in reach.
        near = np.linalg.norm(target[:, :3] - tcp[:, :3], axis=1) < GRASP_QUERY_RADIUS
        grasped = np.zeros(len(near), bool)
        for j in np.unique(self._target_index_np[near]):
            grasped |= (self._target_index_np == j) & self.agent.is_grasping(self.objects[j]).cpu().numpy()
        return DrawerCubeState(
            target_pos=target[:, :3],
            target_quat=target[:, 3:],
            target_layer=self._object_layer_np[envs, self._target_index_np],
            object_names=np.tile(np.array(self.object_names), (len(tcp), 1)),
            object_layer=self._object_layer_np.copy(),
            object_pos=poses[..., :3],
            target_index=self._target_index_np.copy(),
            layer_boxes=boxes,
            drawer_qpos=qpos,
            grasped=grasped & near,
            eef_pos=tcp[:, :3],
            eef_quat=tcp[:, 3:],
        )

    def evaluate(self) -> dict[str, torch.Tensor]:
        state = self.privileged_state()
        in_layer = state.target_in_layer
        clear = in_layer == 0
        raised = state.target_pos[:, 2] > self.lift_height
        pulled = state.target_pos[:, 0] < self.layout.front_x - self.front_margin
        success = clear & (raised | pulled)
        phi = staged_potential(state.eef_pos, state.target_pos, state.grasped, clear, success)
        as_tensor = lambda a, dtype: torch.as_tensor(a, dtype=dtype, device=self.device)  # noqa: E731
        return {
            "success": as_tensor(success, torch.bool),
            "target_clear": as_tensor(clear, torch.bool),
            "target_in_layer": as_tensor(in_layer, torch.long),
            "target_layer": as_tensor(state.target_layer, torch.long),
            "grasped": as_tensor(state.grasped, torch.bool),
            "potential": as_tensor(phi, torch.float32),
        }

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """The staged potential itself; the decision env turns it into shaping differences."""
        return info["potential"]

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        return info["potential"] / 6.0

    # ---------------------------------------------------------- observations
    def _get_obs_agent(self) -> dict[str, torch.Tensor]:
        return {"eef_state": self.eef_state()}

    def eef_state(self) -> torch.Tensor:
        """(B, 8): TCP position, TCP axis-angle (robot base frame), both finger joints.

        The base sits at the world origin with identity orientation (``_initialize_episode``),
        so the TCP's world pose is its base-frame pose.
        """
        tcp = self.agent.tcp.pose.raw_pose
        gripper = self.agent.robot.get_qpos()[:, -2:]
        return torch.cat([tcp[:, :3], quaternion_to_axis_angle(tcp[:, 3:]), gripper], dim=1)

    @contextmanager
    def sensors_paused(self) -> Iterator[None]:
        """Observations inside leave out camera images (no render): for control steps whose
        observation no controller reads."""
        self._sensors_paused = True
        try:
            yield
        finally:
            self._sensors_paused = False

    def _get_obs_with_sensor_data(self, info: dict, apply_texture_transforms: bool = True) -> dict:
        if self._sensors_paused:
            return self._get_obs_state_dict(info)
        return super()._get_obs_with_sensor_data(info, apply_texture_transforms)

    def _get_obs_extra(self, info: dict) -> dict[str, torch.Tensor]:
        opening = self.cabinet.get_qpos()
        poses = torch.stack([actor.pose.raw_pose for actor in self.objects], dim=1)
        envs = torch.arange(len(poses), device=poses.device)
        target = torch.as_tensor(self._target_index_np, device=poses.device)
        in_layer = info["target_in_layer"]
        detection = self._detect(poses[envs, target], in_layer, opening)
        return {"drawer_opening": opening, "target_detection": detection}

    def _detect(self, pose: torch.Tensor, in_layer: torch.Tensor, opening: torch.Tensor) -> torch.Tensor:
        """(B, 8) what a camera sees of objects at ``pose`` (B, 7) inside drawers ``in_layer`` (0: none):
        visible flag and pose, zeros while the drawer around it is open less than ``visible_opening``."""
        idx = (in_layer - 1).clamp(min=0)
        drawer_open = opening.gather(1, idx[:, None])[:, 0] >= self.visible_opening
        visible = (in_layer == 0) | drawer_open
        return torch.cat([visible[:, None].float(), pose * visible[:, None]], dim=1)

    def views(self, state: DrawerCubeState | None = None) -> np.ndarray:
        """(B, M, 8) every object of the episode as a camera sees it now (visible flag, pose), by the
        rule of ``target_detection``; objects the episode leaves out are never seen. ``state``: this
        instant's ``privileged_state()``, when the caller has it already."""
        state = self.privileged_state() if state is None else state
        b, m = state.object_layer.shape
        poses = torch.stack([actor.pose.raw_pose for actor in self.objects], dim=1).cpu().reshape(b * m, 7)
        in_layer = layer_containing(state.object_pos.reshape(b * m, 3), np.repeat(state.layer_boxes, m, axis=0))
        opening = torch.as_tensor(np.repeat(state.drawer_qpos, m, axis=0), dtype=torch.float32)
        seen = self._detect(poses.float(), torch.as_tensor(in_layer), opening).numpy().reshape(b, m, 8)
        return seen * (state.object_layer > 0)[..., None]

    def look_in(self) -> np.ndarray:
        """(B, layers, M, 8): each object of the episode as a camera sees it with drawer L pulled open
        to ``visible_opening`` (its contents carried with it) and the others closed, for every L.

        The observation phase of the observed-memory variant: what a robot that opened each drawer
        once would have seen. Computed on the scene's geometry without stepping the simulator
        (the drawers do not move); objects the episode leaves out are never seen.
        """
        state = self.privileged_state()
        b, m = state.object_layer.shape
        seen = np.zeros((b, len(LAYERS), m, 8), dtype=np.float32)
        closed = np.broadcast_to(self._closed_boxes, (m, *self._closed_boxes.shape))
        for k in range(b):
            quat = np.stack([actor.pose.raw_pose[k, 3:].cpu().numpy() for actor in self.objects])
            in_layer = layer_containing(state.object_pos[k], closed)
            for layer in LAYERS:
                opening = np.zeros((m, len(LAYERS)))
                opening[:, layer - 1] = self.visible_opening
                pos = state.object_pos[k] - (in_layer == layer)[:, None] * [self.visible_opening, 0.0, 0.0]
                pose = torch.as_tensor(np.concatenate([pos, quat], axis=1), dtype=torch.float32)
                view = self._detect(pose, torch.as_tensor(in_layer), torch.as_tensor(opening, dtype=torch.float32))
                seen[k, layer - 1] = view.numpy() * (state.object_layer[k] > 0)[:, None]
        return seen
