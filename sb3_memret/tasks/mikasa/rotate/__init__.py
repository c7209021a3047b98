"""The Rotate family: a peg turned by the angle its instruction names from where it started (``task``), by its expert
(``expert``)."""
