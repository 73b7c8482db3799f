"""Low-pass filters for inertial signals, and the cut-off chosen from the data.

The paper's step 1, a low-pass filter on the raw gyro and accelerometer whose cut-off "is found
experimentally": :func:`cutoff_from_spectrum` finds it from the noise floor of the signal's
spectrum, :func:`lowpass` applies it (causal or zero-phase). (The orientation estimators' own
filters are the vqf package's.)
Frequencies in Hz, times in s.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit.errors import BadInput


def lowpass(x: np.ndarray, cutoff_hz: float, rate_hz: float, zero_phase: bool = False, order: int = 2) -> np.ndarray:
    """Butterworth low pass along axis 0. ``x`` (N, ...); causal unless ``zero_phase``.

    The causal filter starts in steady state at the first sample (no transient from zero).
    """
    x = np.asarray(x, float)
    if not 0 < cutoff_hz < rate_hz / 2:
        raise BadInput(f"low-pass cut-off {cutoff_hz:.4g} Hz must lie between 0 and half the sampling rate "
                       f"({rate_hz / 2:.4g} Hz)")
    from scipy import signal  # here, not at the top: scipy.signal costs platkit orient's start-up a second

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
    from scipy import signal  # not at the top: see lowpass

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
