"""Low-pass filters for inertial signals, and the cut-off chosen from the data.

Two uses: (1) the paper's step 1, a low-pass filter on the raw gyro and accelerometer whose
cut-off "is found experimentally": :func:`cutoff_from_spectrum` finds it from the noise floor
of the signal's spectrum, :func:`lowpass` applies it (causal or zero-phase); (2) the streaming
second-order Butterworth filter :class:`LowPass2` the orientation estimators run sample by sample.
Frequencies in Hz, times in s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from platkit.errors import BadInput


def butter2_coefficients(tau: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Second-order Butterworth low pass whose step response has time constant ``tau`` (s).

    The cut-off is f_c = sqrt(2) / (2 pi tau). Returns (b (3,), a (2,)) for
    y = b0 x + s0; s0' = b1 x - a1 y + s1; s1' = b2 x - a2 y (a0 = 1).
    """
    fc = math.sqrt(2.0) / (2.0 * math.pi * tau)
    C = math.tan(math.pi * fc * dt)
    D = C * C + math.sqrt(2.0) * C + 1.0
    b0 = C * C / D
    return np.array([b0, 2 * b0, b0]), np.array([2 * (C * C - 1) / D, (1 - math.sqrt(2.0) * C + C * C) / D])


class LowPass2:
    """Streaming second-order Butterworth low pass over a vector of channels.

    For the first ``tau`` seconds the output is the running mean of the input; the filter then
    starts in steady state at that mean (no start-up transient from zero).
    """

    def __init__(self, tau: float, dt: float, size: int):
        self.b, self.a = butter2_coefficients(tau, dt)
        self.n_init = max(1, int(math.ceil(tau / dt)))
        self.count = 0
        self.total = np.zeros(size)
        self.s0 = np.zeros(size)
        self.s1 = np.zeros(size)
        self.y = np.zeros(size)

    def step(self, x: np.ndarray) -> np.ndarray:
        b, a = self.b, self.a
        if self.count < self.n_init:
            self.count += 1
            self.total = self.total + x
            self.y = self.total / self.count
            if self.count == self.n_init:
                x0 = self.y
                self.s0 = x0 * (1.0 - b[0])
                self.s1 = x0 * (b[2] - a[1])
            return self.y
        y = b[0] * x + self.s0
        self.s0 = b[1] * x - a[0] * y + self.s1
        self.s1 = b[2] * x - a[1] * y
        self.y = y
        return y


def lowpass(x: np.ndarray, cutoff_hz: float, rate_hz: float, zero_phase: bool = False, order: int = 2) -> np.ndarray:
    """Butterworth low pass along axis 0. ``x`` (N, ...); causal unless ``zero_phase``.

    The causal filter starts in steady state at the first sample (no transient from zero).
    """
    x = np.asarray(x, float)
    if not 0 < cutoff_hz < rate_hz / 2:
        raise BadInput(f"low-pass cut-off {cutoff_hz:.4g} Hz must lie between 0 and half the sampling rate "
                       f"({rate_hz / 2:.4g} Hz)")
    sos = signal.butter(order, cutoff_hz, fs=rate_hz, output="sos")
    if zero_phase:
        return signal.sosfiltfilt(sos, x, axis=0)
    zi = signal.sosfilt_zi(sos)
    zi = zi[(...,) + (None,) * (x.ndim - 1)] * x[0]
    y, _ = signal.sosfilt(sos, x, axis=0, zi=zi)
    return y


@dataclass
class CutoffChoice:
    """A cut-off found from a spectrum: frequency (Hz), the noise floor (unit^2/Hz), the band
    the floor was measured in (Hz) and the upper edge of the motion's band (Hz)."""

    cutoff_hz: float
    noise_floor: float
    floor_band_hz: tuple[float, float]
    signal_edge_hz: float


def cutoff_from_spectrum(x: np.ndarray, rate_hz: float, margin: float = 4.0,
                         min_hz: float = 10.0, headroom: float = 4.0) -> CutoffChoice:
    """Choose a low-pass cut-off where the motion's spectrum sinks into the sensor's noise floor.

    ``x`` (N,) or (N, k) (channels are summed). The noise floor is the median power spectral
    density (Welch) of the upper half of the band, where a platform's motion has no power; the
    signal band ends where the spectrum, rising from 0 Hz, last exceeds ``margin`` times the
    floor. The cut-off is ``headroom`` times that edge (a causal filter delays what it passes by
    about sqrt(2) / (2 pi f_c) s, so it must sit well above the motion), never below ``min_hz``
    and at most 0.45 times the sampling rate.
    """
    x = np.asarray(x, float)
    if x.ndim == 1:
        x = x[:, None]
    n = len(x)
    if n < 64:
        raise BadInput(f"{n} samples are too few to estimate a spectrum (need at least 64)")
    nper = int(min(n, 2 ** int(np.log2(max(64, rate_hz * 4)))))
    f, p = signal.welch(x - x.mean(axis=0), fs=rate_hz, nperseg=nper, axis=0)
    psd = p.sum(axis=1)
    upper = f >= rate_hz / 4
    floor = float(np.median(psd[upper]))
    above = np.nonzero((psd > margin * floor) & (f > 0))[0]
    # the signal band: the longest run of "above the floor" bins starting at the low end
    edge = 0.0
    if above.size:
        run_end = above[0]
        for k in above[1:]:
            if k - run_end > max(2, len(f) // 64):
                break
            run_end = k
        edge = float(f[min(run_end + 1, len(f) - 1)])
    fc = min(max(min_hz, headroom * edge), 0.45 * rate_hz)
    return CutoffChoice(fc, floor, (rate_hz / 4, rate_hz / 2), edge)
