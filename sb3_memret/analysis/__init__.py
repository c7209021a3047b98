"""What a run learned and how a frozen controller consumes memory: held-out evaluation, ablations,
traces of the retriever's scores, learning curves and the run report."""
