"""The BlinkCount family: a lamp's blinks counted, a button pressed that many times (``task``) by its expert
(``expert``)."""
