"""From sub-ray returns to echoes: chains of returns on the pulse's range axis (numpy twin of
:mod:`mitsuforest.scan.echoes`, the tests' reference).

Model (one-way range axis). The emitted pulse is Gaussian in time with FWHM ``pulse_length``; on the
range axis its FWHM is the resolving distance ``ΔR = c·pulse_length / 2`` (``σ = ΔR / 2.3548``). The
received waveform of a pulse whose sub-rays return powers ``p_i`` at ranges ``r_i`` is

    W(x) = Σ_i p_i exp(-½ ((x - r_i) / σ)²).

What is detected. Not the maxima of W, but chains: a pulse's returns are sorted by range and chained
while consecutive ranges are within ΔR (``r_(j+1) - r_j ≤ ΔR``); each chain is one echo candidate at
the chain's energy-weighted mean range ``m``. Its amplitude is the chain's own part of the waveform
at ``m``, ``Σ_(i in chain) p_i exp(-½ ((r_i - m) / σ)²)``: returns of other chains are left out, even
a neighbour just past ΔR, so it is not ``W(m)``. Candidates with amplitude > 0 and
≥ ``detection_threshold`` are echoes; the first ``max_returns`` in range order are kept (0 = no limit).
``scan/echoes.py`` runs the same rule on the device.

When chains and waveform maxima differ. For two returns ``d`` apart with power ratio
``a = p_weak / p_strong``, W has two maxima iff ``δ = d/σ > 2`` and ``a > a_min(δ)``, where

    a_min(δ) = (x₊ / x₋) · exp(-δ √(δ² - 4) / 2),   x± = (δ ± √(δ² - 4)) / 2

(:func:`two_maxima_ratio`): with the stronger return at 0, W' = 0 where
``a = x/(δ - x) · exp(δ²/2 - δx)``; on (0, δ) the right side goes from 0 to ∞, monotonically if
δ ≤ 2, else with a local maximum and minimum where ``x(δ - x) = 1``, and W has three stationary
points (two maxima) iff ``a`` lies between those two values (``a_min`` and ``1/a_min``). The weakest ratio still resolved into two maxima:

    ====================  ======  ======  ======  ======  ======  ======  ======  ======
    separation d / ΔR     ≤ 0.85  0.9     1.0     1.03    1.1     1.25    1.5     2.0
    a_min                 (none)  0.946   0.749   0.683   0.532   0.271   0.061   0.0009
    ====================  ======  ======  ======  ======  ======  ======  ======  ======

and, the other way, the separation a ratio needs: 1 → 0.85 ΔR (= 2σ), 0.75 → 1.00 ΔR,
0.5 → 1.12 ΔR, 0.3 → 1.23 ΔR, 0.1 → 1.42 ΔR, 0.01 → 1.74 ΔR, 0.001 → 1.99 ΔR. So the chain rule

* splits what W merges: two chains more than ΔR apart are two echoes although W has one maximum
  when ``a < a_min`` (e.g. 1.03 ΔR apart with powers 1 : 0.3). Returns of equal power more than ΔR
  apart always give two maxima (``ΔR > 2σ``), so there the rule is right;
* merges what W separates: returns 0.85 ΔR < d ≤ ΔR apart with ``a > a_min(d)`` (e.g. equal powers
  0.9 ΔR apart) are one chain although W has two maxima; and a chain has no length limit, only gaps
  ≤ ΔR, so one long chain can hold several maxima of W.

:func:`waveform_maxima` counts the maxima of W of one pulse; ``benchmarks/stability.py`` measures how
often that count differs from the number of chains in canopy-like pulses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...scan.echoes import FWHM_PER_SIGMA


def waveform_maxima(ranges: np.ndarray, powers: np.ndarray, resolving: float, grid_step: float | None = None) -> int:
    """Number of local maxima of one pulse's summed waveform ``W(x) = Σ p_i exp(-½((x - r_i)/σ)²)``.

    The maxima lie between the nearest and farthest return (W' > 0 before, < 0 after); they are
    counted as sign changes + to - of W', evaluated in closed form on a grid over that span, so a
    maximum and a minimum closer than ``grid_step`` can be missed.

    :param ranges: (S,) return ranges (m); ``inf`` (no return) is ignored.
    :param powers: (S,) return powers; returns of zero power are ignored.
    :param resolving: ΔR (m), the pulse's FWHM on the range axis.
    :param grid_step: grid spacing (m); σ/50 by default.
    """
    ranges, powers = np.asarray(ranges, np.float64), np.asarray(powers, np.float64)
    keep = np.isfinite(ranges) & (powers > 0)
    r, p = ranges[keep], powers[keep]
    if len(r) == 0:
        return 0
    sigma = resolving / FWHM_PER_SIGMA
    step = sigma / 50 if grid_step is None else grid_step
    x = np.arange(r.min() - step, r.max() + 2 * step, step)
    z = (x[:, None] - r) / sigma
    slope = np.sign(-(p * z * np.exp(-0.5 * z ** 2)).sum(axis=1))
    slope = slope[slope != 0]                       # flat where far from every return (underflow)
    return int(np.count_nonzero((slope[:-1] > 0) & (slope[1:] < 0)))


def two_maxima_ratio(separation, resolving: float):
    """The weakest power ratio (weaker / stronger) at which two returns ``separation`` apart give two
    maxima of the waveform: ``a_min(δ)`` of the module docstring, 1 where ``δ = d/σ ≤ 2`` (never).

    :param separation: (n,) or scalar range separation d (m).
    """
    delta = np.abs(np.asarray(separation, np.float64)) / (resolving / FWHM_PER_SIGMA)
    q = np.sqrt(np.maximum(delta ** 2 - 4, 0))
    x_plus, x_minus = (delta + q) / 2, (delta - q) / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = x_plus / x_minus * np.exp(-delta * q / 2)
    return np.where(delta > 2, ratio, 1.0)


@dataclass
class Echoes:
    pulse: np.ndarray              # (E,) row of the pulse in the input arrays
    return_number: np.ndarray      # (E,) uint8, 1.. in range order
    number_of_returns: np.ndarray  # (E,) uint8
    range: np.ndarray              # (E,) float64, energy-weighted mean range (m)
    amplitude: np.ndarray          # (E,) float64 (unit: see radiometry.py)
    dominant: np.ndarray           # (E,) flat index (pulse * S + sub-ray) of the strongest sub-ray
    member: np.ndarray             # (M,) flat indices of the sub-rays forming kept echoes
    member_echo: np.ndarray        # (M,) the echo each member belongs to
    member_weight: np.ndarray      # (M,) the member's share of its echo's energy

    def weighted_mean(self, values: np.ndarray, row_of_ray: np.ndarray | None = None) -> np.ndarray:
        """Energy-weighted mean over each echo's sub-rays of ``values`` -> (E, k).

        :param values: (P*S, k) per sub-ray, or (H, k) per hit with ``row_of_ray`` (P*S,) mapping each
            flat sub-ray index to its row.
        """
        rows = self.member if row_of_ray is None else row_of_ray[self.member]
        v = values[rows] * self.member_weight[:, None]
        out = np.zeros((len(self.pulse), values.shape[1]))  # bincount of nothing would be int64
        for k in range(values.shape[1]):
            out[:, k] = np.bincount(self.member_echo, v[:, k], len(self.pulse))
        return out


@dataclass
class _Groups:
    """Candidate echoes before detection: one per chain of sub-ray returns."""

    pulse: np.ndarray
    range: np.ndarray
    amplitude: np.ndarray
    dominant: np.ndarray
    member: np.ndarray
    member_group: np.ndarray
    member_weight: np.ndarray


def pulse_echoes(ranges: np.ndarray, power: np.ndarray, resolving: float, threshold: float = 0.0,
                  max_returns: int = 0, range_min: float = 0.0, range_max: float = np.inf) -> Echoes:
    """Echoes of P pulses of S sub-rays each: chains of returns within ``resolving`` of the next, with
    the amplitude of each chain's own returns (see the module docstring for how this differs from the
    maxima of the summed waveform).

    :param ranges: (P, S) hit range of each sub-ray (m), ``inf`` where it hit nothing.
    :param power: (P, S) received power of each sub-ray.
    :param resolving: the resolving distance ΔR (m); see ``Sensor.resolving_distance``.
    """
    n_pulses = ranges.shape[0]
    ranges = np.where((ranges >= range_min) & (ranges <= range_max), ranges, np.inf)
    valid = np.isfinite(ranges)
    hit = valid.any(axis=1)
    near = np.where(valid, ranges, np.inf).min(axis=1)
    far = np.where(valid, ranges, -np.inf).max(axis=1)
    single = hit & (far - near <= resolving)         # every return in one chain: no sorting needed
    several = hit & ~single
    sigma = resolving / FWHM_PER_SIGMA
    parts = [_chains(np.flatnonzero(rows), ranges, power, resolving, sigma, sorted_=sorted_)
             for rows, sorted_ in ((single, False), (several, True)) if rows.any()]
    g = _merge(parts) if parts else None
    if g is None:
        empty = np.zeros(0, np.int64)
        return Echoes(empty, empty.astype(np.uint8), empty.astype(np.uint8), np.zeros(0), np.zeros(0),
                      empty, empty, empty, np.zeros(0))
    detected = (g.amplitude > 0) & (g.amplitude >= threshold)
    kept = np.flatnonzero(detected)
    kept_pulse = g.pulse[kept]
    rank = np.arange(len(kept)) - np.searchsorted(kept_pulse, kept_pulse)   # kept is sorted by pulse
    if max_returns:
        keep = rank < max_returns
        kept, kept_pulse, rank = kept[keep], kept_pulse[keep], rank[keep]
    per_pulse = np.bincount(kept_pulse, minlength=n_pulses)
    new_index = np.full(len(g.pulse), -1, np.int64)
    new_index[kept] = np.arange(len(kept))
    member_echo = new_index[g.member_group]
    m = member_echo >= 0
    return Echoes(
        pulse=kept_pulse, return_number=(rank + 1).astype(np.uint8),
        number_of_returns=per_pulse[kept_pulse].astype(np.uint8), range=g.range[kept],
        amplitude=g.amplitude[kept], dominant=g.dominant[kept], member=g.member[m], member_echo=member_echo[m],
        member_weight=g.member_weight[m])


def _chains(rows: np.ndarray, ranges, power, resolving, sigma, sorted_: bool) -> _Groups:
    """Chains of returns of the pulses ``rows``; ``sorted_=False`` when each pulse is one chain."""
    samples = ranges.shape[1]
    r_all = ranges[rows]
    if sorted_:
        order = np.argsort(r_all, axis=1, kind="stable")
        r = np.take_along_axis(r_all, order, 1)
    else:
        order = np.broadcast_to(np.arange(samples), r_all.shape)
        r = r_all
    valid = np.isfinite(r)
    starts = valid.copy()
    if sorted_:
        with np.errstate(invalid="ignore"):  # inf - inf between misses
            starts[:, 1:] &= ~(valid[:, :-1] & (np.diff(r, axis=1) <= resolving))
    else:
        starts[:, 1:] &= ~valid[:, :-1].cumsum(axis=1).astype(bool)  # only each pulse's first return
    local, cols = np.nonzero(valid)                   # row-major: by pulse, then by range
    flat = rows[local] * samples + order[local, cols]
    rv = r[local, cols]
    pv = power.reshape(-1)[flat].astype(np.float64)
    group = np.cumsum(starts[local, cols]) - 1
    n_groups = int(group[-1]) + 1 if len(group) else 0
    energy = np.bincount(group, pv, n_groups)
    count = np.bincount(group, None, n_groups)
    uniform = energy <= 0                             # all-grazing chains: plain mean
    w = np.where(uniform[group], 1.0 / count[group], pv / np.where(uniform, 1, energy)[group])
    mean_range = np.bincount(group, w * rv, n_groups)
    shape = np.exp(-0.5 * ((rv - mean_range[group]) / sigma) ** 2) if sigma > 0 else (rv == mean_range[group])
    amplitude = np.bincount(group, pv * shape, n_groups)
    pulse = np.zeros(n_groups, np.int64)
    pulse[group] = rows[local]
    first = np.flatnonzero(starts[local, cols])
    strongest = np.maximum.reduceat(pv, first) if len(first) else np.zeros(0)
    at_max = np.flatnonzero(pv == strongest[group])
    _, pick = np.unique(group[at_max], return_index=True)
    return _Groups(pulse, mean_range, amplitude, flat[at_max[pick]], flat, group, w)


def _merge(parts: list[_Groups]) -> _Groups:
    """Concatenate candidate echoes and order them by pulse, then range."""
    offsets = np.cumsum([0] + [len(p.pulse) for p in parts[:-1]])
    cat = {k: np.concatenate([getattr(p, k) for p in parts]) for k in ("pulse", "range", "amplitude", "dominant")}
    member = np.concatenate([p.member for p in parts])
    member_group = np.concatenate([p.member_group + o for p, o in zip(parts, offsets)])
    member_weight = np.concatenate([p.member_weight for p in parts])
    order = np.lexsort((cat["range"], cat["pulse"]))
    position = np.empty_like(order)
    position[order] = np.arange(len(order))
    return _Groups(*(cat[k][order] for k in ("pulse", "range", "amplitude", "dominant")),
                   member, position[member_group], member_weight)
