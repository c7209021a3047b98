"""The project's own language-conditioned controller, trained from the expert's demonstrations.

Kept apart as LeRobot keeps its policies: ``configuration`` (what the checkpoint was trained
with), ``modeling`` (the network, saved and loaded as safetensors with a strict check),
``processing`` (observations and prompts to model inputs) and ``controller`` (the frozen
controller the memory serves).
"""

from sb3_memret.controllers.learned.configuration import LearnedPolicyConfig
from sb3_memret.controllers.learned.controller import LearnedController
from sb3_memret.controllers.shipped import default_checkpoint, shipped_names
from sb3_memret.controllers.learned.modeling import LearnedPolicy

__all__ = ["LearnedController", "LearnedPolicy", "LearnedPolicyConfig", "default_checkpoint", "shipped_names"]
