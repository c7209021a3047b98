"""A light Panda for the drawer: ManiSkill's Panda with its visual meshes decimated, so a camera renders three times
faster.

On a CPU (lavapipe) the drawer's two camera pictures cost about the same at any size from 32 to 512 pixels (117 ms
at 128x128, 125 at 224x224), nearly all of it the Panda's 135k visual triangles (hiding the robot leaves 15 ms).
Decimated to a tenth (``KEEP_FRACTION``) they cost 32-38 ms and differ from the full meshes' by 0.36 of 255 on
average at 224x224 (0.7% of the base camera's pixels by more than 8; the wrist camera, which sees only the fingers,
is unchanged; ``scripts/bench_render.py``). Collision meshes, ignored collision pairs, inertias, joints and
controllers are ManiSkill's own: the physics is identical.

The meshes are made on first use from the installed ManiSkill's (a fraction of a second) and kept in
``light_panda_dir()``. The drawer draws it by default (``robot_uids="panda_light"``; ``"panda"`` draws ManiSkill's);
a camera controller trained on one does not carry over to the other (``ControllerSpec.robot`` refuses the pair).
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import mani_skill
from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots.panda.panda import Panda

from sb3_memret.common.cache import CACHE_ENV, cache_root

LIGHT_PANDA_UID = "panda_light"
KEEP_FRACTION = 0.1  # of each visual mesh's triangles; below it a picture gets no cheaper (measured: 0.04 the same)
MIN_FACES = 2000  # meshes smaller than this (the fingers) are kept whole
ASSETS_VERSION = 2  # bump when the recipe changes: the cache folder is named by it
SOURCE_URDF = Path(mani_skill.__file__).parent / "assets" / "robots" / "panda" / "panda_v2.urdf"
VISUAL_PREFIX = 'filename="franka_description/meshes/visual/'
ASSET_PREFIX = 'filename="franka_description/'


def light_panda_dir() -> Path:
    """The folder of the light Panda's URDF and meshes (``$SB3_MEMRET_CACHE``, else ``~/.cache/sb3-memret``)."""
    return cache_root() / f"panda-light-v{ASSETS_VERSION}-mani_skill-{mani_skill.__version__}"


def decimate_glb(source: Path, target: Path, keep: float = KEEP_FRACTION, min_faces: int = MIN_FACES) -> tuple[int, int]:
    """Write ``source``'s scene to ``target`` with every mesh of ``min_faces`` or more cut to ``keep`` of its
    triangles (quadric decimation, vertices merged first, materials and node poses kept). Returns the triangle
    counts before and after."""
    import fast_simplification
    import numpy as np
    import trimesh

    if not 0.0 < keep <= 1.0:
        raise ValueError(f"keep must be in (0, 1], got {keep}")
    scene = trimesh.load(source, force="scene")
    before = after = 0
    for name, mesh in list(scene.geometry.items()):
        before += len(mesh.faces)
        if len(mesh.faces) >= min_faces and keep < 1.0:
            merged = mesh.copy()
            merged.merge_vertices(merge_tex=True, merge_norm=True)  # the files hold 3 vertices a face: weld them
            vertices, faces = fast_simplification.simplify(merged.vertices.astype(np.float32),
                                                           merged.faces.astype(np.int32), target_reduction=1.0 - keep)
            light = trimesh.Trimesh(vertices, faces, process=False)
            light.unmerge_vertices()  # three vertices a face again: flat shading, as the source meshes are drawn
            light.visual = trimesh.visual.TextureVisuals(material=mesh.visual.material)
            scene.geometry[name] = light
        after += len(scene.geometry[name].faces)
    scene.export(target)
    return before, after


def light_panda_urdf() -> Path:
    """The light Panda's URDF, made on first use: visual meshes decimated into the cache, every other file
    (collision meshes) ManiSkill's own, by absolute path. Safe when several processes make it at once."""
    folder = light_panda_dir()
    urdf = folder / "panda_light.urdf"
    if urdf.is_file():
        return urdf
    for source in (SOURCE_URDF, SOURCE_URDF.with_suffix(".srdf")):
        if not source.is_file():
            raise FileNotFoundError(f"ManiSkill's Panda description is missing {source}: reinstall mani-skill")
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=folder.name + ".", dir=folder.parent))
    except OSError as err:
        raise OSError(f"cannot write the light Panda's meshes into {str(folder.parent)!r} ({err.strerror}): set "
                      f"${CACHE_ENV} to a writable folder, or pass robot_uids='panda' for ManiSkill's Panda") from err
    try:
        visual = SOURCE_URDF.parent / "franka_description" / "meshes" / "visual"
        for mesh in sorted(visual.glob("*.glb")):
            decimate_glb(mesh, staging / mesh.name)
        text = SOURCE_URDF.read_text()
        if VISUAL_PREFIX not in text:
            raise ValueError(f"{SOURCE_URDF} names no visual mesh under {VISUAL_PREFIX!r}: this ManiSkill's Panda "
                             "is laid out differently; pass robot_uids='panda'")
        text = text.replace(VISUAL_PREFIX, f'filename="{folder}/')
        text = text.replace(ASSET_PREFIX, f'filename="{SOURCE_URDF.parent / "franka_description"}/')
        (staging / urdf.name).write_text(text)
        # SAPIEN's loader reads the collision pairs to ignore from the .srdf beside the .urdf, by its name
        shutil.copyfile(SOURCE_URDF.with_suffix(".srdf"), staging / urdf.with_suffix(".srdf").name)
        try:
            staging.rename(folder)
        except OSError:  # another process made it first
            if not urdf.is_file():
                raise
    finally:
        if staging.exists():
            shutil.rmtree(staging)
    return urdf


@register_agent()
class LightPanda(Panda):
    """ManiSkill's Panda (same links, joints, collisions and controllers) with visual meshes a tenth as dense."""

    uid = LIGHT_PANDA_UID

    def _load_articulation(self, initial_pose=None):
        self.urdf_path = str(light_panda_urdf())
        super()._load_articulation(initial_pose)


__all__ = ["KEEP_FRACTION", "LIGHT_PANDA_UID", "LightPanda", "decimate_glb", "light_panda_dir", "light_panda_urdf"]
