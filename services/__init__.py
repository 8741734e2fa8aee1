"""lpc services: small asyncio processes on a Zenoh bus, and the ``lpc`` command."""

import os

# The fits solve many tiny systems: threaded BLAS makes them about 3x slower and competes with
# the other services for the cores. Set before numpy is first imported.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
