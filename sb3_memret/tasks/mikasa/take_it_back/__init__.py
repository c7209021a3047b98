"""TakeItBack: a cube pushed onto a target and back to where it started, whose marker the cameras never show (``task``)."""
