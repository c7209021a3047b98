"""The FindImposter family: the objects shown in the cue, then the one among more that was not shown touched (``task``),
read by its own cue readers (``perception``)."""
