"""Each camera draws only the bodies inside its view: the same pictures, bit for bit, for less work on a CPU.

A software renderer (lavapipe) pays for every triangle it is handed, seen or not: the Panda's wrist-camera mount
alone has 425,160, none ever in the wrist camera's own view, and the arm's links are behind it. Before each camera's
picture, every render body it cannot see is made invisible (``visibility`` 0, which the renderer skips when it
records the picture) and restored after: a body whose bounding box lies wholly outside the camera's view frustum,
or one fixed to the camera itself (whose box holds the camera) none of whose triangles lies in view, found once per
process for each such geometry. Such a body covers no pixel, and with rasterised shading and no shadows it changes no other pixel either, so
culling applies only there (``cullable``) and leaves every other scene as ManiSkill renders it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

RASTERISED_SHADERS = frozenset({"minimal", "default"})  # shader packs where a pixel sees only what lies in view
# the eight corners of a unit box, as (0 or 1) weights on an AABB's min and max corners
_CORNERS = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)


PLANES = 6  # left, right, bottom, top, near, far
# whether each (camera, body fixed to it) pair is never in view, by their geometry: the same robot in every scene
# (a scene built anew at each reset) is checked triangle by triangle once per process
_NEVER_IN_VIEW: dict[tuple, bool] = {}


def outside_planes(clip: np.ndarray) -> np.ndarray:
    """Per point of ``clip`` (homogeneous clip coordinates, ... x 4), a bit mask of the frustum planes it lies
    outside (bit i: plane i of ``PLANES``)."""
    x, y, z, w = np.moveaxis(clip, -1, 0)
    mask = np.zeros(x.shape, dtype=np.uint8)
    for bit, side in enumerate((w + x, w - x, w + y, w - y, w + z, w - z)):
        mask |= (side < 0).astype(np.uint8) << np.uint8(bit)
    return mask


def boxes_outside(clip_corners: np.ndarray) -> np.ndarray:
    """Per box (``clip_corners``: B x 8 x 4, each box's corners in clip coordinates), whether it lies wholly outside
    one plane of the frustum: then no part of it reaches a pixel (conservative: a box across a plane's corner region
    stays drawn)."""
    return np.bitwise_and.reduce(outside_planes(clip_corners), axis=1) != 0


def mesh_outside(clip: np.ndarray, triangles: np.ndarray) -> bool:
    """Whether every triangle (vertex indices into ``clip``'s points) lies wholly outside one plane of the frustum."""
    mask = outside_planes(clip)
    return bool(np.all(mask[triangles[:, 0]] & mask[triangles[:, 1]] & mask[triangles[:, 2]]))


def view_to_clip(camera: Any) -> np.ndarray:
    """World to clip coordinates of a ``sapien.render.RenderCameraComponent`` (its pose as of ``update_render``)."""
    return camera.get_projection_matrix() @ np.linalg.inv(camera.get_model_matrix())


def _mount_key(camera: Any, body: Any) -> tuple | None:
    """What decides whether ``body`` fixed to ``camera``'s entity is in its view: the camera's projection and pose on
    the entity, each mesh's file, scale and pose on it; None where a shape is not a mesh read from a file."""
    from sapien.render import RenderShapeTriangleMesh

    shapes = []
    for shape in body.render_shapes:
        if not isinstance(shape, RenderShapeTriangleMesh) or not shape.filename:
            return None
        shapes.append((shape.filename, tuple(shape.scale), tuple(shape.local_pose.p), tuple(shape.local_pose.q)))
    pose = camera.local_pose
    return (tuple(camera.get_projection_matrix().ravel()), tuple(pose.p), tuple(pose.q), tuple(shapes))


def never_in_view(camera: Any, body: Any) -> bool:
    """Whether ``body``, fixed to the camera's own entity (so it moves with it), has no triangle in the camera's
    view: the wrist camera's own mount. Checked triangle by triangle once per geometry (``_mount_key``)."""
    key = _mount_key(camera, body)
    if key is None:
        return _triangles_out_of_view(camera, body)
    if key not in _NEVER_IN_VIEW:
        _NEVER_IN_VIEW[key] = _triangles_out_of_view(camera, body)
    return _NEVER_IN_VIEW[key]


def _triangles_out_of_view(camera: Any, body: Any) -> bool:
    """Whether every triangle of ``body``'s meshes lies wholly outside one plane of ``camera``'s frustum (a primitive
    shape, whose box alone is known, counts as in view)."""
    from sapien.render import RenderShapeTriangleMesh

    to_clip = view_to_clip(camera) @ body.entity.pose.to_transformation_matrix()
    for shape in body.render_shapes:
        if not isinstance(shape, RenderShapeTriangleMesh):
            return False
        shape_to_clip = to_clip @ shape.local_pose.to_transformation_matrix() @ np.diag([*shape.scale, 1.0])
        for part in shape.parts:
            vertices = np.asarray(part.get_vertices(), dtype=np.float64)
            clip = np.hstack([vertices, np.ones((len(vertices), 1))]) @ shape_to_clip.T
            if not mesh_outside(clip, np.asarray(part.get_triangles(), dtype=np.int64)):
                return False
    return True


def cullable(env: Any) -> bool:
    """Whether culling leaves ``env``'s pictures unchanged: one CPU-simulated scene, rasterised camera shaders and no
    light casting shadows (a body out of view could shade one in view)."""
    scene = env.scene
    if scene.gpu_sim_enabled or len(scene.sub_scenes) != 1:
        return False
    system = scene.sub_scenes[0].render_system
    if any(getattr(light, "shadow", False) for light in system.lights):
        return False
    return all(getattr(sensor.config, "shader_pack", None) in RASTERISED_SHADERS for sensor in env._sensors.values())


class FrustumCull:
    """ManiSkill's ``capture_sensor_data`` for a ManiSkill env, each camera taking its picture with the render
    bodies outside its view made invisible, then restored; an env that is not ``cullable`` captures as before."""

    def __init__(self, env: Any):
        self._env = env
        self._capture = env.capture_sensor_data
        self._system: Any = None  # the render system the blind bodies were found in (a rebuilt scene has another)
        self._blind: dict[str, list[Any]] = {}  # camera name -> the bodies fixed to it that it never sees

    def install(self) -> None:
        """Take over the env's ``capture_sensor_data`` (ManiSkill's one path to its cameras' pictures)."""
        self._env.capture_sensor_data = self.capture

    def capture(self) -> None:
        """Take every sensor's picture, each camera's without the bodies it cannot see."""
        from mani_skill.sensors.camera import Camera

        env = self._env
        if not cullable(env):
            self._capture()
            return
        system = env.scene.sub_scenes[0].render_system
        if system is not self._system:
            self._system, self._blind = system, {}
        bodies = [body for body in system.render_bodies if body.is_enabled and body.visibility > 0]
        for name, sensor in env._sensors.items():
            if not isinstance(sensor, Camera):
                sensor.capture()
                continue
            camera = sensor.camera._render_cameras[0]
            if name not in self._blind:
                self._blind[name] = [body for body in bodies
                                     if body.entity is camera.entity and never_in_view(camera, body)]
            hidden = [(body, body.visibility) for body in self.hidden(camera, bodies, self._blind[name])]
            for body, _ in hidden:
                body.visibility = 0.0
            try:
                sensor.capture()
            finally:
                for body, visibility in hidden:
                    body.visibility = visibility

    @staticmethod
    def hidden(camera: Any, bodies: list[Any], blind: list[Any]) -> list[Any]:
        """Of ``bodies``, those ``camera`` cannot see now: ``blind`` ones, and those whose box is out of its view."""
        out = [body for body in blind if body in bodies]
        boxed, lows, highs = [], [], []
        for body in bodies:
            if body in blind:
                continue
            low, high = np.asarray(body.get_global_aabb_fast(), dtype=np.float64)
            if np.all(np.isfinite(low)) and np.all(np.isfinite(high)):  # an unbounded shape may be anywhere in view
                boxed.append(body)
                lows.append(low)
                highs.append(high)
        if boxed:
            low, high = np.array(lows)[:, None, :], np.array(highs)[:, None, :]
            corners = low + _CORNERS[None] * (high - low)  # (B, 8, 3)
            clip = np.concatenate([corners, np.ones((*corners.shape[:2], 1))], axis=-1) @ view_to_clip(camera).T
            out += [body for body, outside in zip(boxed, boxes_outside(clip)) if outside]
        return out


__all__ = ["FrustumCull", "boxes_outside", "cullable", "mesh_outside", "never_in_view", "outside_planes"]
