"""Perception: from a depth frame to a grasp target.

Scan-line cutting (``scans``, ``intrinsics``), the 2-D fit models (``fit``) and their
model-free RANSAC machinery (``ransac``), the 3-D solids (``solids``), the two reconstruction
methods (``laser``: the paper's four lines; ``cloud``: the full-cloud benchmark), their common
result (``reconstruction``), the 10-frame window (``window``), the reconstructor's and scans'
message-level steps (``reconstructor``, ``pipeline``), and the camera's frame gate that sheds
perception before control when the control path runs late (``shedding``).

The lowest layer: imports nothing else from ``lpc_core``.
"""
