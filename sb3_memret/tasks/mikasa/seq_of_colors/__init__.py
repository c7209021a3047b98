"""The SeqOfColors family: the colours a cue shows, each touched afterwards in any order (``task``)."""
