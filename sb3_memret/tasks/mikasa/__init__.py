"""MIKASA-Robo-VLA memory tasks (the ``mikasa-robo-suite`` package) as sb3-memret tasks, and the parts a task of
your own reuses:

- ``MikasaCueTask``: the base class of a task whose memory is one word about a cue shown once (its class
  attributes are documented on it), with ``CueWriter`` (its writer) and ``EVAL_SEED`` (MIKASA's first evaluation
  seed);
- readers, one base-camera frame in, the cue's word out: ``read_cue_colour`` (``COLOUR_NAMES``, MIKASA's colour
  order) and ``read_cue_shape`` (``SHAPE_NAMES``);
- controller views, wrappers that cut MIKASA's observation to joints, hand, cameras and an object detector:
  ``DetectorObservation`` (any objects), ``ControllerObservation`` (RememberColor's cubes),
  ``ShapeControllerObservation`` (RememberShape's objects);
- experts: ``ScriptedTouchController`` (touches the object its prompt's word names; ``TouchGains`` its motion);
- experts on the harness's inputs alone (``scripted-camera``, ``camera_experts``): ``camera_expert(task)``,
  ``register_camera_expert`` (one for a task class of your own), ``CameraTouchController`` (RememberColor's),
  ``CameraButtonPressController`` (BlinkCount's), ``CameraTimedTransferController`` (TimedTransfer's),
  ``CameraCarryBackController`` (TakeItBack's), ``CameraImposterController`` (FindImposter's),
  ``DeadReckonedHand`` (the hand's motion from its pose), ``HeldCube`` (a carried cube, followed by its grip);
- for a task whose memory is several facts (the colour-cue tasks): ``SeqOfColorsTask`` (any of their 18 ids),
  ``SequenceWriter`` (one fact per cue item, and progress as memory), ``SequenceTouchController`` (touches the
  prompt's colours in their ordinal order, then presses the button), ``SeqControllerObservation`` (its view, with
  the button), ``CameraSequenceController`` (the same expert on the harness's inputs alone: ``scripted-camera``),
  ``read_cube_layout``, ``CubeLayout`` and ``read_cue_set`` (where each cube stands, tracked over an episode, which
  colours a frame shows),
  ``sequence_facts`` and ``item_key`` (the items' wording and memory keys), and ``PROGRESS_WORDINGS`` with
  ``TOUCHED_FACT`` and ``PRESSED_FACT`` (what has been done, worded).

The names import on first use: the package itself imports nothing heavy.

Layout: ``core/`` holds what the families share (the cue-task base, the pixel readers, the touch, carry and sequence
experts, MIKASA's lamp and its lit-bulb reader, the base camera's calibration, the demonstration layout); each family
has a folder of its own (``remember/``, ``find_imposter/``, ``shell_game/``, ``intercept/``, ``rotate/``,
``blink_count/``, ``seq_of_colors/``, ``take_it_back/``, ``gather_and_recall/``, ``timed_transfer/``,
``trace_shape/``) with its task, and its expert and readers where it has its own;
``assets/`` holds the files the wheel ships.
"""

from __future__ import annotations

from sb3_memret.common.lazy import lazy_exports

_EXPORTS = {
    "CueWriter": "core.cue_task", "EVAL_SEED": "core.cue_task", "MikasaCueTask": "core.cue_task",
    "COLOUR_NAMES": "core.perception", "ControllerObservation": "core.perception",
    "DetectorObservation": "core.perception", "read_cue_colour": "core.perception",
    "SHAPE_NAMES": "core.shape_perception", "ShapeControllerObservation": "core.shape_perception",
    "read_cue_shape": "core.shape_perception",
    "ScriptedTouchController": "core.touch_expert", "TouchGains": "core.touch_expert",
    "SequenceTouchController": "core.sequence_expert", "TOUCHED_FACT": "core.sequence_expert",
    "PRESSED_FACT": "core.sequence_expert",
    "read_cube_layout": "core.layout_perception", "read_cue_set": "core.layout_perception",
    "CubeLayout": "core.layout_perception", "CameraSequenceController": "seq_of_colors.camera_expert",
    "CameraTouchController": "remember.camera_expert", "DeadReckonedHand": "core.hand_motion",
    "CameraButtonPressController": "blink_count.camera_expert",
    "CameraTimedTransferController": "timed_transfer.camera_expert",
    "CameraCarryBackController": "take_it_back.camera_expert", "HeldCube": "core.held_object",
    "CameraImposterController": "find_imposter.camera_expert",
    "camera_expert": "camera_experts", "register_camera_expert": "camera_experts",
    "SeqOfColorsTask": "seq_of_colors.task", "SeqControllerObservation": "seq_of_colors.task",
    "SequenceWriter": "seq_of_colors.writer", "sequence_facts": "seq_of_colors.writer",
    "item_key": "seq_of_colors.writer", "PROGRESS_WORDINGS": "seq_of_colors.writer",
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())

__all__ = sorted(_EXPORTS)
