"""The experts on what MIKASA's harness gives a policy alone (``--controller scripted-camera``), per task family.

A task's ``expert()`` reads a simulated detector and the arm's joints: a privileged upper bound. Where a family's
objects can be read from the base camera with its shipped calibration, its camera expert plays the same motion on
the harness's inputs (``ControllerSpec.harness_inputs``), and its tables are protocol entries. They are kept here,
not on the task classes, so that a task's code (and the benchmark cells its digest keys) stays as it was played.
``register_camera_expert`` adds one for a task class of your own.

The shipped ones, and what each reads from the base camera (its module's docstring says how, and how well):

- Seq-, Chain-, BunchOfColors: the cubes by colour, the button; what was done from its prompt's progress facts;
- RememberColor: the cubes by colour; RememberShape, RememberShapeAndColor: the objects named against FindImposter's
  exemplars of the same objects;
- FindImposter: cubes by colour, or objects named against the task's exemplars once every place is filled;
- BlinkCountButtonPress: the red button's cap, the phase lamp; TimedTransfer: the cube; TakeItBack: the cube, the
  target and its turn to purple;
- Rotate: the peg at every call (whole, both ends, or a strip beside the hand); Intercept: the ball at every call,
  the target;
- TraceShape, TraceShapeSeq: the green cube (again where it fell), the button's cap; GatherAndRecall: the cubes, the
  buttons, the disc laid from them;
- BatteriesChecker: the batteries standing in the tray, the socket and the button laid from it; a battery let go is
  read again once at rest.

Every one dead-reckons the hand's motion from its pose (the harness gives no joint velocities) and follows what it
carries by the grip.
"""

from __future__ import annotations

import importlib
from typing import Callable

from sb3_memret.controllers.base import FrozenController
from sb3_memret.tasks.base import Task

CameraExpertBuilder = Callable[[Task], FrozenController]
_REGISTERED: dict[type, CameraExpertBuilder] = {}  # a user's own, by register_camera_expert


def register_camera_expert(task_class: type, build: CameraExpertBuilder) -> None:
    """Make ``build(task)`` the camera expert of ``task_class`` and its subclasses (a later registration of the same
    class replaces it)."""
    if not (isinstance(task_class, type) and issubclass(task_class, Task)):
        raise TypeError(f"task_class must be a Task subclass, got {task_class!r}")
    if not callable(build):
        raise TypeError(f"build must be callable (task -> FrozenController), got {build!r}")
    _REGISTERED[task_class] = build


def _builders() -> dict[type, CameraExpertBuilder]:
    """Task class -> camera expert builder: the package's own (their task modules import on first use: they import
    MIKASA), then the registered ones."""
    builders = {getattr(importlib.import_module(module), name): build for module, name, build in _SHIPPED}
    return {**builders, **_REGISTERED}


def _builder(task: Task) -> CameraExpertBuilder | None:
    builders = _builders()
    return next((builders[cls] for cls in type(task).__mro__ if cls in builders), None)


def has_camera_expert(task: Task) -> bool:
    """Whether ``task`` (or a base class of it) has a camera expert."""
    return _builder(task) is not None


def camera_expert(task: Task) -> FrozenController:
    """``task``'s expert on the harness's inputs alone; a task without one is refused in a line naming those that
    have one."""
    build = _builder(task)
    if build is None:
        families = ", ".join(sorted(cls.__name__ for cls in _builders()))
        raise ValueError(f"task {task.name!r} has no expert on the cameras alone (scripted-camera); the task classes "
                         f"that have one: {families}; use 'scripted' for its expert on a simulated detector (a "
                         "privileged upper bound)")
    return build(task)


def _colour_sequence(task: Task) -> FrozenController:
    """The colour-cue tasks (Seq-, Chain-, BunchOfColors): cubes and button from the base camera, what was done from
    the prompt's progress facts."""
    from sb3_memret.tasks.mikasa.seq_of_colors.camera_expert import CameraSequenceController

    if not task.progress:
        raise ValueError(f"{task.name}'s camera expert learns what it has done from its prompt's progress facts; "
                         "SeqOfColorsTask(progress=False) words none")
    shown_at_once = task.n_items if task.variant.together else 1
    return CameraSequenceController(task.template, shown_at_once, paced_every=task.replan_every)


def _remember_colour(task: Task) -> FrozenController:
    """RememberColor 3/5/9 and their -Long: the cubes from the base camera."""
    from sb3_memret.tasks.mikasa.remember.camera_expert import CameraTouchController

    return CameraTouchController(task.words, task.template, paced_every=task.replan_every, default=task.words[0],
                                 wait_for_all=not task.noop_before_manipulation)


def _remember_shape(task: Task) -> FrozenController:
    """RememberShape 3/5/9, RememberShapeAndColor 3x2/3x3/5x3 and their -Long: the objects from the base camera,
    named by FindImposter's reader against the exemplars of the FindImposter task with the same objects."""
    from sb3_memret.tasks.mikasa.remember.shape_camera_expert import CameraShapeTouchController, shape_places

    return CameraShapeTouchController(task.words, task.template, task.field, paced_every=task.replan_every,
                                      read_layout=shape_places(task.name, task.words), default=task.words[0],
                                      wait_for_all=not task.noop_before_manipulation)


def _blink_count(task: Task) -> FrozenController:
    """BlinkCountButtonPress Easy/Medium/Hard and their -Long: the red button and the phase lamp from the base
    camera, the presses made from the prompt's progress facts."""
    from sb3_memret.tasks.mikasa.blink_count.camera_expert import CameraButtonPressController

    if not task.progress:
        raise ValueError(f"{task.name}'s camera expert learns the presses made from its prompt's progress facts; "
                         "BlinkCountTask(progress=False) words none")
    return CameraButtonPressController(task.template, paced_every=task.replan_every, default_count=1)


def _timed_transfer(task: Task) -> FrozenController:
    """TimedTransfer Easy/Medium/Hard and their -Long: the cube from the base camera, the red disc where MIKASA lays
    it from the cube's disc, the grip from the gripper's opening."""
    from sb3_memret.tasks.mikasa.timed_transfer.camera_expert import CameraTimedTransferController

    return CameraTimedTransferController(task.template, paced_every=task.replan_every)


def _take_it_back(task: Task) -> FrozenController:
    """TakeItBack: the cube and the red target from the base camera, the target's turn to purple, the grip from the
    gripper opening."""
    from sb3_memret.tasks.mikasa.take_it_back.camera_expert import CameraCarryBackController
    from sb3_memret.tasks.mikasa.take_it_back.task import DEFAULT_SIDE, SIDE_CENTRES

    return CameraCarryBackController(SIDE_CENTRES, DEFAULT_SIDE, task.template, paced_every=task.replan_every)


def _rotate(task: Task) -> FrozenController:
    """Rotate Lenient and Strict: the peg from the base camera at every call, in hand once gripped; the wrist's angle
    from the hand's pose."""
    from sb3_memret.tasks.mikasa.rotate.camera_expert import CameraPegTurnController
    from sb3_memret.tasks.mikasa.rotate.task import DEFAULT_START_DEG

    return CameraPegTurnController(task.template, task.strategy, DEFAULT_START_DEG, paced_every=task.replan_every)


def _intercept(task: Task) -> FrozenController:
    """Intercept and InterceptGrab: the ball from the base camera at every call (where its last sighting and the
    prompt's velocity put it while unseen), the target from the first frame, the grip from the gripper opening."""
    from sb3_memret.tasks.mikasa.intercept.camera_expert import CameraInterceptController

    return CameraInterceptController(task.template, task.default_speed, carry=task.variant.carry,
                                     paced_every=task.replan_every)


def _trace_shape(task: Task) -> FrozenController:
    """TraceShape Easy/Medium/Hard: the green cube from the base camera, then in hand."""
    from sb3_memret.tasks.mikasa.trace_shape.camera_expert import CameraTraceShapeController

    return CameraTraceShapeController(task.template, paced_every=task.replan_every)


def _trace_sequence(task: Task) -> FrozenController:
    """TraceShapeSeq Easy/Medium/Hard: the green cube and the button's cap from the base camera, the paths traced
    from the prompt's progress facts."""
    from sb3_memret.tasks.mikasa.trace_shape.camera_expert import CameraTraceSequenceController

    return CameraTraceSequenceController(task.template, paced_every=task.replan_every)


def _gather(task: Task) -> FrozenController:
    """GatherAndRecall 1/3/5/7/9: the cubes and the buttons from the base camera's first frame, the disc where MIKASA
    lays it from the buttons, the cubes carried by the grip."""
    from sb3_memret.tasks.mikasa.gather_and_recall.camera_expert import CameraGatherPressController

    return CameraGatherPressController(task.template, task.words, default=task.words[0], n_cubes=task.n_cubes,
                                       paced_every=task.replan_every)


def _imposter(task: Task) -> FrozenController:
    """FindImposter Color, Shape and ShapeAndColor: every object placed from the frame that shows them all (cubes by
    colour, as RememberColor's; objects of several shapes by the writer's reader); the imposter chosen as the
    detector's expert does."""
    from sb3_memret.tasks.mikasa.find_imposter.camera_expert import CameraImposterController, imposter_places
    from sb3_memret.tasks.mikasa.find_imposter.perception import task_exemplars

    places = None
    if task.reads_shapes:
        places = imposter_places(task.words, [task.candidate(w) for w in task.words], task_exemplars(task.name))
    return CameraImposterController(task.expert(), places, paced_every=task.replan_every)


def _batteries(task: Task) -> FrozenController:
    """BatteriesChecker Easy and Hard: the tray's batteries from the base camera's first frame, the socket and the
    button where MIKASA lays them from the tray, a battery let go read again once at rest."""
    from sb3_memret.tasks.mikasa.batteries_checker.camera_expert import CameraBatteryCheckController

    return CameraBatteryCheckController(task.template, task.variant.hard, task.variant.batteries,
                                        paced_every=task.replan_every)


_SHIPPED: tuple[tuple[str, str, CameraExpertBuilder], ...] = (
    ("sb3_memret.tasks.mikasa.seq_of_colors.task", "SeqOfColorsTask", _colour_sequence),
    ("sb3_memret.tasks.mikasa.remember.color", "RememberColorTask", _remember_colour),
    ("sb3_memret.tasks.mikasa.remember.shape", "RememberShapeTask", _remember_shape),
    ("sb3_memret.tasks.mikasa.remember.shape_and_color", "RememberShapeAndColorTask", _remember_shape),
    ("sb3_memret.tasks.mikasa.blink_count.task", "BlinkCountTask", _blink_count),
    ("sb3_memret.tasks.mikasa.timed_transfer.task", "TimedTransferTask", _timed_transfer),
    ("sb3_memret.tasks.mikasa.take_it_back.task", "TakeItBackTask", _take_it_back),
    ("sb3_memret.tasks.mikasa.find_imposter.task", "FindImposterTask", _imposter),
    ("sb3_memret.tasks.mikasa.rotate.task", "RotateTask", _rotate),
    ("sb3_memret.tasks.mikasa.intercept.task", "InterceptTask", _intercept),
    ("sb3_memret.tasks.mikasa.trace_shape.task", "TraceShapeTask", _trace_shape),
    ("sb3_memret.tasks.mikasa.gather_and_recall.task", "GatherAndRecallTask", _gather),
    ("sb3_memret.tasks.mikasa.trace_shape.sequence", "TraceShapeSeqTask", _trace_sequence),
    ("sb3_memret.tasks.mikasa.batteries_checker.task", "BatteriesCheckerTask", _batteries),
)

__all__ = ["camera_expert", "has_camera_expert", "register_camera_expert"]
