"""``--controller`` values: parsing, the errors for malformed ones, and what they build."""

import socket
import sys

import pytest

from sb3_memret.tasks.drawer import DrawerTask

from sb3_memret.controller_specs import CONTROLLER_SPECS, make_controller, parse_lerobot_spec, parse_openpi_spec
from sb3_memret.tasks.drawer.expert import ScriptedDrawerController
from sb3_memret.controllers.harness_proprio import HARNESS_PROPRIO_NAMES
from sb3_memret.controllers.shipped import SHIPPED, shipped_names


def test_scripted():
    assert isinstance(make_controller("scripted", "drawer"), ScriptedDrawerController)


@pytest.mark.parametrize("spec, expected", [
    ("openpi://localhost:8000", ("localhost", 8000, {})),
    ("openpi://10.1.2.3:9000?timeout=60&attempts=5", ("10.1.2.3", 9000, {"timeout": 60.0, "attempts": 5})),
    ("openpi://gpu-box:8000?chunk_len=10", ("gpu-box", 8000, {"chunk_len": 10})),
    ("openpi://[::1]:8000", ("::1", 8000, {})),
])
def test_openpi_specs(spec, expected):
    assert parse_openpi_spec(spec) == expected


@pytest.mark.parametrize("spec, message", [
    ("openpi://localhost", "malformed openpi controller 'openpi://localhost'"),
    ("openpi://:8000", "malformed openpi controller"),
    ("openpi://localhost:99999", "malformed openpi controller"),
    ("openpi://localhost:port", "malformed openpi controller"),
    ("openpi://localhost:8000/policy", "malformed openpi controller"),
    ("openpi:localhost:8000", "malformed openpi controller"),
    ("openpi://localhost:8000?timeout=soon", r"option timeout='soon' .* is not a valid float"),
    ("openpi://localhost:8000?retries=3", r"bad option 'retries'='3'.*\['attempts', 'chunk_len', 'timeout'\]"),
    ("openpi://localhost:8000?timeout=1&timeout=2", "bad option 'timeout'='2'"),
    ("openpi://localhost:8000?timeout=", "bad option 'timeout'=''"),
    ("openpi://localhost:8000?timeout", "bad option"),
])
def test_malformed_openpi_specs_are_refused_with_the_accepted_form(spec, message):
    with pytest.raises(ValueError, match=message) as err:
        make_controller(spec, "drawer")
    assert spec in str(err.value)


@pytest.mark.parametrize("spec, expected", [
    ("lerobot:/ckpt/pi05", ("/ckpt/pi05", {})),
    ("lerobot:runs/pi05?device=cuda", ("runs/pi05", {"device": "cuda"})),
    ("lerobot:/ckpt?adapter=/lora&tokenizer=/tok", ("/ckpt", {"adapter": "/lora", "tokenizer": "/tok"})),
])
def test_lerobot_specs(spec, expected):
    assert parse_lerobot_spec(spec) == expected


@pytest.mark.parametrize("spec, message", [
    ("lerobot:", "malformed lerobot controller 'lerobot:'"),
    ("lerobot:?adapter=/lora", "malformed lerobot controller"),
    ("lerobot:/ckpt?adaptor=/lora", r"bad option 'adaptor'.*\['adapter', 'device', 'tokenizer'\]"),
    ("lerobot:/ckpt?adapter=", "bad option 'adapter'=''"),
])
def test_malformed_lerobot_specs_are_refused(spec, message):
    with pytest.raises(ValueError, match=message):
        make_controller(spec, "drawer")


@pytest.mark.parametrize("spec", ["pi0", "openpi", "lerobot", "Scripted", " scripted"])
def test_unknown_specs_list_every_accepted_form(spec):
    with pytest.raises(ValueError, match=r"unknown controller|malformed") as err:
        make_controller(spec, "drawer")
    if "unknown" in str(err.value):
        assert all(form in str(err.value) for form in CONTROLLER_SPECS)


def test_openpi_spec_builds_the_client_with_its_options(monkeypatch):
    pytest.importorskip("openpi_client", reason="openpi-client is not installed")
    from sb3_memret.controllers import openpi

    built = {}
    monkeypatch.setattr(openpi, "OpenPIController", lambda host, port, **kw: built.update(host=host, port=port, **kw))
    make_controller("openpi://gpu-box:8000?timeout=60&attempts=5&chunk_len=10", "drawer")
    assert built == {"host": "gpu-box", "port": 8000, "chunk_len": 10, "task_template": DrawerTask().prompt_template,
                     "limits": openpi.ServerLimits(infer_timeout=60.0, attempts=5)}


def test_openpi_spec_of_a_server_that_is_down_fails_fast():
    pytest.importorskip("openpi_client", reason="openpi-client is not installed")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(ConnectionError, match=rf"ws://127\.0\.0\.1:{port}: connect failed 1 times"):
        make_controller(f"openpi://127.0.0.1:{port}?attempts=1", "drawer")


def test_lerobot_spec_passes_its_options(monkeypatch):
    from sb3_memret.controllers import lerobot_pi05

    built = {}
    monkeypatch.setattr(lerobot_pi05, "LeRobotPi05Controller", lambda path, **kw: built.update(path=path, **kw))
    make_controller("lerobot:/ckpt?adapter=/lora&tokenizer=/tok&device=cpu", "drawer")
    assert built == {"path": "/ckpt", "adapter": "/lora", "tokenizer": "/tok", "device": "cpu",
                     "prompt_template": DrawerTask().prompt_template}  # the prompts of the task it acts on


def test_openpi_spec_without_openpi_client_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "openpi_client", None)  # as if not installed
    monkeypatch.delitem(sys.modules, "sb3_memret.controllers.openpi", raising=False)
    with pytest.raises(ImportError, match=r"pip install --no-deps openpi-client==0\.1\.2.*sb3-memret\[openpi\]"):
        make_controller("openpi://localhost:8000", "drawer")


def test_lerobot_spec_of_a_missing_folder_names_it(tmp_path):
    with pytest.raises(FileNotFoundError, match=rf"checkpoint folder {tmp_path / 'nope'} does not exist"):
        make_controller(f"lerobot:{tmp_path / 'nope'}", "drawer")


def test_each_task_names_its_default_controller():
    from sb3_memret.tasks import make_task

    assert make_task("drawer").default_controller == "learned"  # the main job reads cameras
    assert make_task("RememberColor3-VLA-v0").default_controller == "learned"  # its shipped camera controller
    assert make_task("InterceptFast-VLA-v0").default_controller == "learned"
    assert make_task("TimedTransferEasy-VLA-v0").default_controller == "learned"  # sets down in the window now
    # the one camera controller reads these prompts but does not yet do the tasks: their experts
    for task in ("SeqOfColors3-VLA-v0", "RotateLenientPos-VLA-v0", "RotateStrictPos-VLA-v0"):
        assert "learned" in shipped_names(task)
        assert make_task(task).default_controller == "scripted"


@pytest.mark.parametrize("task", sorted(task for task, name in SHIPPED if name == "learned"))
def test_the_shipped_learned_controllers_read_cameras_and_proprioception_only(task):
    from sb3_memret.tasks import make_task

    the_task = make_task(task)
    controller = make_controller("learned", task)
    config = controller.policy.config
    assert controller.spec.needs_images and len(config.image_features) == 2
    if task == "drawer":
        assert config.state_names == the_task.proprio_names()
    else:  # a MIKASA task: the harness's inputs alone (its 7-D proprioception, both cameras), a protocol entry
        assert controller.spec.harness_inputs and tuple(config.state_names) == HARNESS_PROPRIO_NAMES
    # everything else of the task's layout (the object detector, drawer openings) is estimated from the images; one
    # controller across tasks estimates every task's objects, its own among them
    perceived = set(the_task.state_names()) - set(the_task.proprio_names())
    if config.tasks:
        assert task in config.tasks and perceived <= set(config.perceived_names)
    else:
        assert set(config.perceived_names) == perceived


def test_one_camera_controller_serves_the_multitask_tasks_and_each_keeps_its_own():
    from sb3_memret.controllers.shipped import MULTITASK_TASKS, default_checkpoint

    shared = {default_checkpoint("learned", task) for task in MULTITASK_TASKS}
    assert len(shared) == 1  # one checkpoint for all of them
    (folder,) = shared
    config = make_controller("learned", MULTITASK_TASKS[0]).policy.config
    assert set(config.tasks) == set(MULTITASK_TASKS)
    own = [task for task in MULTITASK_TASKS if (task, "learned-task") in SHIPPED]
    assert own and all(default_checkpoint("learned-task", task) != folder for task in own)
    with pytest.raises(ValueError, match="no shipped learned controller 'learned-task' for task 'drawer'"):
        make_controller("learned-task", "drawer")
