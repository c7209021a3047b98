"""What the MIKASA-Robo-VLA families share: the cue-task base (``cue_task``), the pixel readers (``perception``: colours
and the object detector; ``shape_perception``; ``layout_perception``), the experts several families build on
(``touch_expert``, ``carry_expert``, ``sequence_expert``), MIKASA's lamp (``lamp_asset``) and the demonstration
layout (``demo_layout``)."""
