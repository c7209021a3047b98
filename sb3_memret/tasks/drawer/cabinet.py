"""A procedurally built three-drawer cabinet: geometry, and the SAPIEN articulation.

The cabinet is made of boxes and prismatic joints only, so it needs no asset download and
builds without render materials when the scene cannot render. ``CabinetLayout`` is the
single source of truth for its geometry: the task builds from it, the success check reads
drawer boxes from it, and the scripted controller knows the (fixed) scene from it the way
a policy trained on this scene would.

Frames: the robot base sits at the world origin facing +x. The cabinet front face is the
plane ``x = front_x``; drawers open towards the robot (their joint value is the opening in
metres). Layer 1 is the top drawer, layer 3 the bottom one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien

LAYERS: tuple[int, ...] = (1, 2, 3)


@dataclass(frozen=True)
class CabinetLayout:
    """Dimensions in metres of the cabinet, its drawers and their handles."""

    front_x: float = 0.80
    width: float = 0.42
    depth: float = 0.38
    plinth_height: float = 0.08
    slot_height: float = 0.13
    wall: float = 0.012
    drawer_clearance: float = 0.006
    drawer_inner_length: float = 0.30
    drawer_wall_height: float = 0.07
    drawer_travel: float = 0.30
    handle_standoff: float = 0.06
    handle_half_size: tuple[float, float, float] = (0.01, 0.01, 0.05)

    @property
    def num_layers(self) -> int:
        return len(LAYERS)

    @property
    def top_z(self) -> float:
        """Height of the cabinet's top face."""
        return self.plinth_height + self.num_layers * self.slot_height + self.wall

    @property
    def drawer_inner_width(self) -> float:
        return self.width - 4 * self.wall - 2 * self.drawer_clearance

    def slot_bottom_z(self, layer: int) -> float:
        """Height of the bottom of the slot that holds drawer ``layer`` (1 = top)."""
        check_layer(layer)
        return self.plinth_height + (self.num_layers - layer) * self.slot_height

    def drawer_floor_z(self, layer: int) -> float:
        """Height of the inner floor of drawer ``layer``, where objects rest."""
        return self.slot_bottom_z(layer) + self.wall + self.drawer_clearance + self.wall

    def handle_center(self, layer: int, opening: float = 0.0) -> np.ndarray:
        """World position of the centre of drawer ``layer``'s handle bar at ``opening``."""
        z = self.slot_bottom_z(layer) + self.wall + self.drawer_clearance + self._front_height / 2
        return np.array([self.front_x - self.handle_standoff - opening, 0.0, z])

    def inner_box(self, layer: int, opening: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned (low, high) corners of drawer ``layer``'s interior at ``opening``.

        The box runs from the drawer's inner floor to the rim of its walls; an object whose
        centre lies inside it is "in drawer layer ``layer``".
        """
        x0 = self.front_x - opening + self.wall
        floor = self.drawer_floor_z(layer)
        half_w = self.drawer_inner_width / 2
        low = np.array([x0, -half_w, floor])
        high = np.array([x0 + self.drawer_inner_length, half_w, floor + self.drawer_wall_height])
        return low, high

    @property
    def _front_height(self) -> float:
        return self.slot_height - self.wall - 2 * self.drawer_clearance


def check_layer(layer: int) -> int:
    """Return ``layer`` if it names a drawer, else raise a ValueError saying what is valid."""
    if isinstance(layer, bool) or not isinstance(layer, (int, np.integer)) or layer not in LAYERS:
        raise ValueError(f"drawer layer must be one of {list(LAYERS)} (1 = top), got {layer!r}")
    return int(layer)


def build_cabinet(scene, layout: CabinetLayout, name: str = "cabinet"):
    """Build the cabinet articulation in a ManiSkill scene and return it.

    The carcass is the fixed root link; each drawer is a child link on a prismatic joint
    named ``drawer_{layer}_joint``. Visual shapes are added only if the scene can render.
    """
    render = scene.can_render()
    wood = _material((0.55, 0.40, 0.28)) if render else None
    metal = _material((0.75, 0.75, 0.78)) if render else None
    builder = scene.create_articulation_builder()
    builder.initial_pose = sapien.Pose(p=[layout.front_x, 0.0, 0.0])

    carcass = builder.create_link_builder()
    carcass.set_name("carcass")
    _add_carcass_boxes(carcass, layout, wood)

    joint_frame = sapien.Pose(q=[0.0, 0.0, 0.0, 1.0])  # 180 deg about z: +joint moves to -x
    for layer in LAYERS:
        drawer = builder.create_link_builder(carcass)
        drawer.set_name(f"drawer_{layer}")
        drawer.set_joint_name(f"drawer_{layer}_joint")
        slot_z = layout.slot_bottom_z(layer) + layout.wall + layout.drawer_clearance
        drawer.set_joint_properties(
            "prismatic",
            limits=[[0.0, layout.drawer_travel]],
            pose_in_parent=sapien.Pose(p=[0.0, 0.0, slot_z], q=joint_frame.q),
            pose_in_child=sapien.Pose(q=joint_frame.q),
            friction=0.05,
            damping=8.0,
        )
        _add_drawer_boxes(drawer, layout, wood, metal)
    return builder.build(name=name, fix_root_link=True)


def _material(rgb: tuple[float, float, float]):
    return sapien.render.RenderMaterial(base_color=[*rgb, 1.0], roughness=0.8)


def _box(link, center, half_size, material) -> None:
    pose = sapien.Pose(p=list(center))
    link.add_box_collision(pose, half_size=list(half_size), density=400)
    if material is not None:
        link.add_box_visual(pose, half_size=list(half_size), material=material)


def _add_carcass_boxes(link, lay: CabinetLayout, material) -> None:
    """Carcass in the cabinet frame: x back from the front face, z up from the floor."""
    w, hd, hw = lay.wall, lay.depth / 2, lay.width / 2
    top = lay.top_z
    _box(link, (hd, 0, lay.plinth_height / 2), (hd, hw, lay.plinth_height / 2), material)
    _box(link, (lay.depth - w / 2, 0, top / 2), (w / 2, hw, top / 2), material)
    for side in (-1, 1):
        _box(link, (hd, side * (hw - w / 2), top / 2), (hd, w / 2, top / 2), material)
    for k in range(1, lay.num_layers + 1):
        z = lay.plinth_height + k * lay.slot_height + w / 2
        _box(link, (hd, 0, z), (hd, hw - w, w / 2), material)


def _add_drawer_boxes(link, lay: CabinetLayout, material, handle_material) -> None:
    """Drawer in its link frame: origin at the front face's bottom centre, x into the cabinet."""
    w = lay.wall
    inner_w, inner_l, wall_h = lay.drawer_inner_width, lay.drawer_inner_length, lay.drawer_wall_height
    front_h = lay._front_height
    front_hw = lay.width / 2 - w - lay.drawer_clearance
    _box(link, (w / 2, 0, front_h / 2), (w / 2, front_hw, front_h / 2), material)
    _box(link, (w + inner_l / 2, 0, w / 2), (inner_l / 2, inner_w / 2 + w, w / 2), material)
    _box(link, (w + inner_l + w / 2, 0, (wall_h + w) / 2), (w / 2, inner_w / 2 + w, (wall_h + w) / 2), material)
    for side in (-1, 1):
        _box(link, (w + inner_l / 2, side * (inner_w / 2 + w / 2), (wall_h + w) / 2),
             (inner_l / 2, w / 2, (wall_h + w) / 2), material)
    # Handle: a vertical bar held off the front face by two horizontal posts.
    hx, hy, hz = lay.handle_half_size
    mid_z = front_h / 2
    _box(link, (-lay.handle_standoff, 0, mid_z), (hx, hy, hz), handle_material)
    for side in (-1, 1):
        post_len = lay.handle_standoff - hx
        _box(link, (-post_len / 2, 0, mid_z + side * (hz - hx)), (post_len / 2, hy, hx), handle_material)
