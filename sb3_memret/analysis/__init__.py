"""What a run learned and how a frozen controller consumes memory: ablations, traces of the retriever's
scores, learning curves and the run report (held-out evaluation itself is ``sb3_memret.evaluation.retrieval``)."""
