"""The Remember family: a cue's colour (``color``), shape (``shape``) or both (``shape_and_color``) shown once, the
object that matches it touched later."""
