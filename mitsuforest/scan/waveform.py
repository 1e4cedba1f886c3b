"""The sampled received waveform of each pulse, and the records of a batch's pulses (``output.waveforms``,
``output.pulses``).

Model. The received waveform of a pulse whose sub-rays return powers ``p_i`` at ranges ``r_i`` is the
echo model's (:mod:`mitsuforest.testing.reference.echoes`)

    W(x) = Σ_i p_i exp(-½ ((x - r_i) / σ)²),   σ = ΔR / 2.3548,

on the one-way range axis x (m), ΔR the sensor's resolving distance (``c·pulse_length/2`` unless the
sensor gives ``echo_separation``), in the amplitude unit of radiometry.py: a lone return of power p
peaks at p, which is its echo's amplitude.

Sampling. The digitiser's clock starts at emission: bin k covers two-way times
``[k·Δt, (k+1)·Δt)``, ranges ``[k·h, (k+1)·h)`` with ``h = c·Δt/2`` (Δt the sensor's
``waveform.bin_size``). A pulse's window is ``waveform.samples`` bins from ``first_bin``, the bin
holding ``r_first - 5σ`` (``r_first`` its nearest sub-ray return). Each sample is the mean of W over its
bin (an integrating digitiser), computed in closed form with erf, so ``h · Σ samples`` is the integral
of W over the window for any pulse length, however short against the bin. A return's shape is
summed over ``r_i ± 5σ`` (it leaves out 6e-7 of its integral); a pulse is ``complete`` when its
farthest return's ``r_i + 5σ`` lies inside the window and its nearest return's ``r_i - 5σ`` is not
before emission (range 0, where every window starts at the latest).

On the device. A render samples on the device (:func:`device_waveforms`, one lane per pulse adding
the bins of its returns into its window in turn, float32 but for each bin's start less the return's
range, float64: the same bytes in every run);
:func:`sample_waveforms` is its numpy twin (float64) and the tests' reference.

Echo energy. An echo's energy is the integral of its own chain's part of W:
``E = σ·√(2π)·Σ_(i in chain) p_i`` (amplitude × m). So a complete waveform's integral equals the
sum of its echoes' energies when every chain of the pulse is an echo (none below
``detection_threshold``, none past ``max_returns``). Speckle scales an echo's amplitude only; the
waveform and the energies are its mean (speckle-free).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.special import erf

from .echoes import FWHM_PER_SIGMA
from .kernel import evaluate_and_wait

REACH_SIGMAS = 5.0          # a return's shape is summed over ± this many σ; windows start this far before the first
CHUNK_RETURNS = 1 << 17     # sub-rays sampled at once (bounds the (returns, bins) temporaries to ~20 MB)


def pulse_sigma(resolving: float) -> float:
    """σ (m) of the pulse shape on the range axis, from the resolving distance ΔR (its FWHM)."""
    return resolving / FWHM_PER_SIGMA


def echo_energy(chain_power, sigma: float):
    """Energy of echoes (amplitude × m): the integral over range of their chains' waveform,
    ``σ·√(2π)·Σ p`` for a chain of total power ``Σ p`` (``chain_power``, (E,))."""
    return np.asarray(chain_power, np.float64) * (sigma * math.sqrt(2 * math.pi))


def sample_waveforms(ranges: np.ndarray, powers: np.ndarray, sigma: float, bin_range: float,
                     samples: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sampled waveforms of P pulses (see the module docstring).

    :param ranges: (P, S) sub-ray return ranges (m), ``inf`` where a sub-ray gave no valid return;
        every pulse must have at least one finite range.
    :param powers: (P, S) received powers (amplitude unit).
    :param sigma: σ of the pulse shape on the range axis (m, > 0; :func:`pulse_sigma`).
    :param bin_range: h, one bin on the range axis (m).
    :param samples: B, bins per window.
    :returns: ``first_bin`` (P,) int64, the window's first bin on the emission clock (its range
        ``first_bin·h``); ``waveform`` (P, B) float32, the mean of W over each bin; ``complete`` (P,)
        bool, whether every return's shape lies inside the window.
    """
    ranges = np.asarray(ranges, np.float64)
    powers = np.asarray(powers, np.float64)
    n = len(ranges)
    valid = np.isfinite(ranges)
    reach = REACH_SIGMAS * sigma
    nearest = np.where(valid, ranges, np.inf).min(axis=1, initial=np.inf)
    farthest = np.where(valid, ranges, -np.inf).max(axis=1, initial=-np.inf)
    if n and not np.isfinite(nearest).all():
        raise ValueError("every pulse needs a return to anchor its window")
    first_bin = np.floor(np.maximum(nearest - reach, 0.0) / bin_range).astype(np.int64)
    complete = (nearest - reach >= 0.0) & (farthest + reach <= (first_bin + samples) * bin_range)
    out = np.zeros((n, samples), np.float32)
    block = max(1, CHUNK_RETURNS // max(ranges.shape[1], 1))               # pulses sampled at once
    for lo in range(0, n, block):
        rows = slice(lo, lo + block)
        out[rows] = _bin_means(ranges[rows], powers[rows], valid[rows], first_bin[rows], sigma, bin_range, samples)
    return first_bin, out, complete


def _bin_means(ranges, powers, valid, first_bin, sigma: float, bin_range: float, samples: int) -> np.ndarray:
    """(P, B) float64 bin means of W for a block of pulses (see :func:`sample_waveforms`)."""
    n = len(ranges)
    reach = REACH_SIGMAS * sigma
    pulse, sub = np.nonzero(valid)
    r, p = ranges[pulse, sub], powers[pulse, sub]
    span = int(math.ceil(2 * reach / bin_range)) + 1                       # bins one return's shape can touch
    low = np.floor((r - reach) / bin_range).astype(np.int64)               # absolute bin of the shape's start
    edges = (low[:, None] + np.arange(span + 1)) * bin_range               # (R, span+1) bin edges (m)
    cdf = erf((edges - r[:, None]) / (sigma * math.sqrt(2.0)))
    part = (p[:, None] * (sigma * math.sqrt(math.pi / 2) / bin_range)) * np.diff(cdf, axis=1)
    local = low[:, None] + np.arange(span) - first_bin[pulse, None]       # bin within the window
    inside = (local >= 0) & (local < samples)
    flat = (pulse[:, None] * samples + local)[inside]
    return np.bincount(flat, part[inside], minlength=n * samples).reshape(n, samples)


def device_waveforms(t: mi.Float, power: mi.Float, samples_per_pulse: int, sigma: float, bin_range: float,
                     samples: int) -> dict:
    """:func:`sample_waveforms` on the device, for the P pulses of a batch, of which M have a return.

    :param t, power: Float (P·S,) each sub-ray's range (``inf`` without a valid return) and power,
        lane = pulse·S + sub-ray (the echo kernel's layout).
    :param samples_per_pulse: S.
    :returns: ``rows`` UInt32 (M,), the pulses with a return; ``first_bin`` UInt32 (M,); ``waveform``
        Float (M·B,), row-major (M, B); ``complete`` Bool (M,). Evaluated.
    """
    Float = type(t)
    UInt32 = dr.uint32_array_t(Float)
    S, B = samples_per_pulse, samples
    reach = REACH_SIGMAS * sigma
    base = dr.arange(UInt32, dr.width(t) // S) * S
    nearest, farthest = dr.full(Float, dr.inf, dr.width(base)), dr.full(Float, -dr.inf, dr.width(base))
    for k in range(S):
        tk = dr.gather(Float, t, base + k)
        nearest = dr.minimum(nearest, tk)
        farthest = dr.maximum(farthest, dr.select(dr.isfinite(tk), tk, -dr.inf))
    evaluate_and_wait(nearest, farthest)
    rows = dr.compress(dr.isfinite(nearest))
    m = dr.width(rows)
    if m == 0:
        return {"rows": rows, "first_bin": UInt32(), "waveform": Float(), "complete": dr.mask_t(Float)()}
    Float64 = dr.float64_array_t(Float)         # bin edges far from the sensor: see _add_returns
    near = Float64(dr.gather(Float, nearest, rows)) - reach
    first = dr.floor(dr.maximum(near, 0.0) / bin_range)
    complete = (near >= 0.0) & (Float64(dr.gather(Float, farthest, rows)) + reach <= (first + B) * bin_range)
    first_bin = UInt32(first)
    waveform = dr.zeros(Float, m * B)
    _add_returns(waveform, t, power, rows, first, S, B, sigma, bin_range)
    evaluate_and_wait(rows, first_bin, waveform, complete)
    return {"rows": rows, "first_bin": first_bin, "waveform": waveform, "complete": complete}


@dr.syntax
def _add_returns(waveform: mi.Float, t: mi.Float, power: mi.Float, rows: mi.UInt32, first: mi.Float64, S: int,
                 B: int, sigma: float, bin_range: float) -> None:
    """Add each return's bins into its pulse's window of ``waveform`` (M·B,), one lane per pulse adding
    its S returns' bins in turn: each bin is summed in the same order whatever the threads or the batch,
    so the waveforms are the same bytes in every run (lanes per return and bin, added at once, are not).

    A bin's start less the return's range is taken in float64, then the erf in float32: in float32,
    ``k·h - r`` keeps only ~1e-3 m at 10 km (1 % of a 1 ns pulse's σ; the samples were off by 6e-3 of
    the peak there and by 1e-4 from 250 m), the float64 difference is as exact near and far."""
    reach = REACH_SIGMAS * sigma
    span = int(math.ceil(2 * reach / bin_range)) + 1        # the bins a return's ± reach can touch
    scale = 1.0 / (sigma * math.sqrt(2.0))
    gain = sigma * math.sqrt(math.pi / 2) / bin_range
    row = dr.arange(mi.UInt32, dr.width(rows))
    base = rows * S
    step = mi.UInt32(0)
    while step < S * span:
        sub, j = step // span, step % span
        r, p = dr.gather(mi.Float, t, base + sub), dr.gather(mi.Float, power, base + sub)
        valid = dr.isfinite(r)
        r = mi.Float64(dr.select(valid, r, 0.0))
        k = dr.floor((r - reach) / bin_range) + mi.Float64(j)      # the bin's absolute index
        start = mi.Float(k * bin_range - r)                         # the bin's start less the return's range
        part = p * gain * (dr.erf((start + bin_range) * scale) - dr.erf(start * scale))
        local = k - first
        inside = valid & (local >= 0) & (local < B)
        dr.scatter_reduce(dr.ReduceOp.Add, waveform, part, row * B + mi.UInt32(dr.maximum(local, 0.0)), inside)
        step += 1


@dataclass
class PulseBatch:
    """One scan batch's pulse records for ``output.waveforms`` and ``output.pulses`` (local frame).

    ``cast``: the cast pulses with at least one sub-ray return (M rows): ``pulse_id``, ``gps_time``,
    ``scan_angle`` (rad), ``origin`` (M, 3), ``direction`` (M, 3) unit beam axis, and their sampled
    waveforms ``samples`` (M, B), ``first_bin`` and ``complete`` (M,) (:func:`device_waveforms`); None
    without ``output.waveforms``. ``echoes``: the kernel's echoes (E rows, in pulse then range
    order): ``pulse_id``, ``return_number``, ``range`` (with ranging noise, as the points),
    ``amplitude`` (with speckle, as the points' intensity), ``energy`` (Σ p of the echo's chain).
    ``fired``: every pulse fired (F rows: ``pulse_id``, ``gps_time``, ``scan_angle``, ``origin``,
    ``direction``), or None when pulse records are not asked for. ``source_id``: the flight line.
    """

    cast: dict
    echoes: dict
    fired: dict | None
    source_id: int

    def echo_counts(self, pulse_id: np.ndarray) -> np.ndarray:
        """(n,) number of echoes of each of the pulses ``pulse_id`` (ascending, as in a batch)."""
        rows = np.searchsorted(pulse_id, self.echoes["pulse_id"])
        return np.bincount(rows, minlength=len(pulse_id)).astype(np.uint16)
