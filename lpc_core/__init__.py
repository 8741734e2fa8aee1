"""lpc_core: the pure algorithms of lpc.

Nothing in this package does I/O, reads a clock or touches the bus. Randomness comes from a
``numpy.random.Generator`` seeded by the caller (the frame's ``seq``), so every result can be
reproduced in a test or a replay.
"""
