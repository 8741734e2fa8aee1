"""lpc services: small asyncio processes on a Zenoh bus, and the ``lpc`` command."""
