"""The Intercept family: a rolling ball's speed read in the cue, the ball intercepted or grabbed (``task``) by its
expert (``expert``)."""
