"""sb3-memret: a learnable external language memory for frozen robot policies."""

import warnings

__version__ = "0.1.0"

# SAPIEN warns at import when the system has no libvulkan and uses the Vulkan loader it bundles,
# which is what renders here (with render_backend="cpu", the project's lavapipe behind it).
warnings.filterwarnings("ignore", message="Failed to find system libvulkan", category=UserWarning)
