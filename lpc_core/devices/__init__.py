"""Devices: bytes on the wire, with no I/O of their own.

What a hand takes and reports (``hand``), the CAN layouts (``can_protocol``), the EAI tactor
controller's framing (``tactor_protocol``) and the tactor bridge's pure logic
(``tactor_bridge``), lpc's serial EMG frame (``emg_protocol``). The drivers in
``services.drivers`` open the ports and call these.

May import ``lpc_core.perception``; never ``control``, ``sim`` or the top-level modules.
"""
