"""GatherAndRecall: cubes gathered onto a disc while a lamp flashes, the flash's colour touched afterwards (``task``) by
its expert (``expert``)."""
