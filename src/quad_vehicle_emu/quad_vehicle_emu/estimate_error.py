"""How an autopilot's estimate differs from the truth, measured the same way on a recorded flight (PX4's logged
estimate and SIH's truth) and on the emulator's Estimate, so that one can be fitted to the other.

- Lag: the shift L that makes the estimate closest to the truth L earlier, min over L of
  RMS(est(t) - truth(t - L) - mean); on a flight that moves fast (a 0.7 Hz oscillation) the minimum is sharp.
- Band RMS: the square root of the Welch power spectral density of the mean-removed error (20 s segments)
  integrated over a band, as the PX4 SIH data set states its error per band (0.05-0.5, 0.5-2, 2-10 Hz).
"""

import csv
import gzip

import numpy as np
from scipy.signal import welch

from quad_common.types import State
from quad_vehicle_emu.plant import plant_flags, plant_from_flags

BANDS_HZ = ((0.05, 0.5), (0.5, 2.0), (2.0, 10.0))
LAGS_S = np.round(np.arange(-0.3, 0.3001, 0.01), 3)   # the shifts searched
SEGMENT_S = 20.0
AXES = ('x_m', 'y_m', 'vx_mps', 'vy_mps')


def best_lag_s(t_s, truth, estimate, lags_s=LAGS_S) -> float:
    """The shift (s; > 0: the estimate trails the truth) with the smallest mean-removed RMS of est(t) - truth(t - L),
    over the times where truth(t - L) is inside the record for every L searched."""
    t_s, truth, estimate = (np.asarray(a, dtype=float) for a in (t_s, truth, estimate))
    inside = (t_s - max(lags_s) >= t_s[0]) & (t_s - min(lags_s) <= t_s[-1])
    rms = []
    for lag_s in lags_s:
        error = estimate[inside] - np.interp(t_s[inside] - lag_s, t_s, truth)
        rms.append(np.sqrt(np.mean((error - error.mean()) ** 2)))
    return float(lags_s[int(np.argmin(rms))])


def band_rms(error, rate_hz: float, bands_hz=BANDS_HZ) -> tuple:
    """The error's RMS in each band (Hz), from its Welch PSD (mean removed, SEGMENT_S segments or the whole)."""
    error = np.asarray(error, dtype=float)
    freq, psd = welch(error - error.mean(), fs=rate_hz, nperseg=min(len(error), int(SEGMENT_S * rate_hz)))
    return tuple(float(np.sqrt(np.trapezoid(psd[(freq >= lo) & (freq < hi)], freq[(freq >= lo) & (freq < hi)])))
                 for lo, hi in bands_hz)


def read_flights(path) -> dict:
    """{flight: {column: array}} from a gzipped CSV with a `flight` column and numeric others (as the PX4 SIH
    extract in quad_bringup's test data: t_s, truth_* and est_* of x_m, y_m, vx_mps, vy_mps)."""
    with gzip.open(path, 'rt') as f:
        rows = list(csv.DictReader(f))
    flights = {}
    for name in dict.fromkeys(r['flight'] for r in rows):
        mine = [r for r in rows if r['flight'] == name]
        flights[name] = {k: np.array([float(r[k]) for r in mine]) for k in mine[0] if k != 'flight'}
    return flights


def emulated_estimate(flight: dict, flags, seed: int = 0, rate_hz: float = 100.0) -> dict:
    """The emulator's estimate (plant_from_flags(flags)'s Estimate, stepped at rate_hz as the emulator's loop does)
    of a flight's recorded horizontal truth (height held), at the flight's times: {est_x_m, est_y_m, est_vx_mps,
    est_vy_mps}."""
    plant = plant_from_flags(plant_flags((*flags, '--seed', str(seed))))
    t_s = flight['t_s']
    ticks = np.arange(0.0, t_s[-1], 1.0 / rate_hz)
    truth = {k: np.interp(ticks, t_s, flight[f'truth_{k}']) for k in AXES}
    estimated = []
    for i, t in enumerate(ticks):
        state = State(position=np.array([truth['x_m'][i], truth['y_m'][i], 2.0]),
                      velocity=np.array([truth['vx_mps'][i], truth['vy_mps'][i], 0.0]))
        e = plant.estimate.step(t, state)
        estimated.append((*e.position[:2], *e.velocity[:2]))
    estimated = np.array(estimated)
    return {f'est_{k}': np.interp(t_s, ticks, estimated[:, i]) for i, k in enumerate(AXES)}
