"""Stable-baselines3 callbacks for training memory policies: rollout retrieval statistics, held-out evaluation with
best-model saving, an early stop at a retrieval target, per-round checkpoints, one progress bar for the run, and
where its time goes."""

from sb3_memret.callbacks.checkpoint import RoundCheckpointCallback, checkpoint_path, latest_checkpoint
from sb3_memret.callbacks.early_stop import StopOnRetrievalTarget
from sb3_memret.callbacks.evaluation import RetrievalEvalCallback
from sb3_memret.callbacks.progress import RunProgressCallback
from sb3_memret.callbacks.rollout_metrics import RolloutRetrievalCallback
from sb3_memret.callbacks.timing import PhaseTimingCallback

__all__ = ["PhaseTimingCallback", "RetrievalEvalCallback", "RolloutRetrievalCallback", "RoundCheckpointCallback",
           "RunProgressCallback", "StopOnRetrievalTarget", "checkpoint_path", "latest_checkpoint"]
