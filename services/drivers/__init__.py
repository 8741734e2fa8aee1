"""Device drivers: small synchronous interfaces, each with a simulated backend.

Drivers follow python-can's shape: the constructor opens the device, ``send(msg, timeout)`` and
``recv(timeout)`` (``None`` on timeout) move messages, ``shutdown()`` may be called twice. Their
errors share one hierarchy, in ``services.drivers.errors``. asyncio meets a driver in exactly one
place, its service's bridge.
"""
