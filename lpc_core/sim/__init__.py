"""Simulation: stand-ins for the world, the sensor, the user and the hand.

The scene and its renderer (``scene``), the simulated depth camera (``simcam``), scripted
timelines (``timeline``), the simulated EMG user (``emg_sim``), the virtual user of the trials
(``virtual_user``) and the simulated hand (``hand``).

May import ``perception``, ``control`` and ``devices`` (to render what a sensor sees and to play
what a device reports); never the top-level modules.
"""
