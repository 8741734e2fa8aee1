"""lpc_core: the pure algorithms of lpc.

Nothing in this package does I/O, reads a clock or touches the bus. Randomness comes from a
``numpy.random.Generator`` seeded by the caller (the frame's ``seq``), so every result can be
reproduced in a test or a replay.

The subpackages are layers, lowest first; a module imports only from its own layer or lower
ones (``tests/test_layers.py`` reads every import and holds the tree to this):

- ``perception``: depth to scan lines to shapes, grasp targets and the 10-frame window.
- ``control``: aim guidance, EMG intent, the controller's state machine. May use perception.
- ``devices``: the wire codecs (CAN, tactor serial, EMG serial) and the tactor bridge's pure
  logic. May use perception (never control: a codec does not decide).
- ``sim``: the scene, the simulated camera, EMG user, virtual user, timelines and hand. May use
  every layer above, to render what a sensor sees and to play the user the controller expects.
- this package's own modules (``replay``, ``trials``, ``foxglove_convert``, ``gaps``) tie the
  layers together and may use any of them.
"""
