"""MIKASA's base camera: the shipped calibration the writers cast pixels with is the simulator's, in every task family
whose writer uses it. Development seed only."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.core.calibration import (  # noqa: E402
    BASE_CAMERA_EXTRINSIC,
    BASE_CAMERA_INTRINSIC,
    BASE_CAMERA_SIZE,
)
from sb3_memret.tasks.mikasa.core.cue_task import DEV_SEED  # noqa: E402

#: one env per family whose writer reads the shipped calibration (ShellGame's too, but its YCB mug is not shipped)
WRITER_FAMILIES = ("TakeItBack-VLA-v0", "RotateLenientPosNeg-VLA-v0", "InterceptMedium-VLA-v0",
                   "BlinkCountButtonPressMedium-VLA-v0", "SeqOfColors3-VLA-v0", "TraceShapeHard-VLA-v0",
                   "TraceShapeSeqEasy-VLA-v0")


@pytest.mark.parametrize("env_id", WRITER_FAMILIES)
def test_the_shipped_calibration_is_the_simulators(env_id):
    """The camera is mounted alike without a renderer (state_dict: a tenth of rgb's build time; checked equal)."""
    env = make_task(env_id).make_env(obs_mode="state_dict", render_backend="cpu", sim_backend="cpu", robot_uids="panda")
    try:
        env.reset(seed=DEV_SEED)
        params = env.unwrapped.get_sensor_params()["base_camera"]
        assert np.allclose(as_numpy(params["intrinsic_cv"])[0], BASE_CAMERA_INTRINSIC, rtol=0, atol=1e-6)
        assert np.allclose(as_numpy(params["extrinsic_cv"])[0], BASE_CAMERA_EXTRINSIC, rtol=0, atol=1e-6)
        config = env.unwrapped.scene.sensors["base_camera"].config
        assert (config.width, config.height) == (BASE_CAMERA_SIZE, BASE_CAMERA_SIZE)
    finally:
        env.close()
