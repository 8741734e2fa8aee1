"""A simulated LSL EMG amplifier: a real pylsl outlet pushing raw EMG with a known envelope.

Channel c carries Gaussian noise inside the EMG band (40-350 Hz, below 0.35 of the rate) of
standard deviation ``envelope(t) * gain[c]`` volts, plus 50 Hz mains hum and an electrode
offset, where ``envelope(t)`` is a slow sine (``SIM_ENVELOPE_V``); the envelope filter should
return its mean absolute value, ``envelope * sqrt(2/pi)``. Samples are paced by the monotonic
clock in chunks of about 5 ms.
``--pause-at S --pause S`` closes the outlet at S seconds and opens it again (same name and
source id) after the pause: the amplifier unplugged and back; SIGUSR1 does the same at once
(a test's cue). Run it in its own process:

    python -m services.drivers.emg_lsl_sim --name lpc-emg --rate 2000 --scope machine
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

import numpy as np
from scipy import signal as sp_signal

from services.drivers.emg_raw import LSL_SCOPES, import_pylsl

SIM_ENVELOPE_V = (1e-4, 5e-5)  # mean and swing of the envelope (V), at 0.5 Hz
# Per channel: the extensor (1) at half the flexor's (0) amplitude; channel 3 carries hum and
# offset only, so a test can tell which channels were read.
GAIN = (1.0, 0.5, 0.25, 0.0)


def sim_envelope(t: np.ndarray) -> np.ndarray:
    """The drive's standard deviation (V) at times ``t`` (s since the outlet's start)."""
    mean, swing = SIM_ENVELOPE_V
    return mean + swing * np.sin(2 * np.pi * 0.5 * t)


def run(
    name: str,
    rate: float,
    duration: float,
    scope: str | None,
    pause_at: float | None = None,
    pause: float = 2.0,
    seed: int = 0,
) -> int:
    pylsl = import_pylsl(scope)
    rng = np.random.default_rng(seed)
    band = sp_signal.butter(4, (40.0, min(350.0, 0.35 * rate)), "bandpass", fs=rate, output="sos")
    # The band-passed noise's standard deviation, to scale it back to one.
    unit = np.std(sp_signal.sosfilt(band, np.random.default_rng(1).standard_normal(200_000)))
    zi = np.zeros((len(band), 2, len(GAIN)))

    def open_outlet():  # type: ignore[no-untyped-def]
        info = pylsl.StreamInfo(name, "EMG", len(GAIN), rate, pylsl.cf_float32, f"{name}-sim")
        return pylsl.StreamOutlet(info, chunk_size=max(1, round(rate * 0.005)))

    cue = threading.Event()
    signal.signal(signal.SIGUSR1, lambda *_: cue.set())
    outlet = open_outlet()
    print(f"outlet {name} open at {rate:g} Hz", flush=True)
    start = time.monotonic()
    sent = 0
    while True:
        now = time.monotonic() - start
        if now >= duration:
            break
        if cue.is_set() or (pause_at is not None and now >= pause_at):
            cue.clear()
            pause_at = None
            del outlet  # the outlet disappears from the network
            print(f"outlet closed at {now:.3f} s", flush=True)
            time.sleep(pause)
            outlet = open_outlet()
            print(f"outlet reopened at {time.monotonic() - start:.3f} s", flush=True)
            # No backlog: an amplifier that was off has nothing to send for the pause.
            sent = int((time.monotonic() - start) * rate)
            continue
        due = int(now * rate) - sent
        if due > 0:
            t = (sent + np.arange(due)) / rate
            noise, zi = sp_signal.sosfilt(
                band, rng.standard_normal((due, len(GAIN))), axis=0, zi=zi
            )
            noise /= unit
            x = noise * sim_envelope(t)[:, None] * np.asarray(GAIN)
            x += 3e-4 * np.sin(2 * np.pi * 50.0 * t)[:, None] + 1e-3
            outlet.push_chunk(x.astype(np.float32))
            sent += due
        time.sleep(0.005)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m services.drivers.emg_lsl_sim", description=__doc__
    )
    parser.add_argument("--name", default="lpc-emg-sim")
    parser.add_argument("--rate", type=float, default=2000.0)
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--scope", choices=LSL_SCOPES, default="machine")
    parser.add_argument("--pause-at", type=float, metavar="S")
    parser.add_argument("--pause", type=float, default=2.0, metavar="S")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    try:
        return run(
            args.name, args.rate, args.duration, args.scope, args.pause_at, args.pause, args.seed
        )
    except KeyboardInterrupt:  # SIGINT is how a bench or a person stops it
        return 0


if __name__ == "__main__":
    sys.exit(main())
