"""Control: what the user is guided to do and what the hand is told to do.

Aim guidance (``aim``: capture-volume hull, aim cue, tactor amplitudes), EMG intent (``emg``:
normalisation, moving average, triggers and co-contraction), the controller's transition table
and step (``controller``) and the immutable-state helper they share (``state``).

May import ``lpc_core.perception``; never ``devices``, ``sim`` or the top-level modules.
"""
