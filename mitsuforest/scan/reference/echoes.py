"""From sub-ray returns to echoes: the pulse's waveform, reduced to its separable peaks (numpy twin of
:mod:`mitsuforest.scan.echoes`, the tests' reference).

Model (one-way range axis). The emitted pulse is Gaussian in time with FWHM ``pulse_length``; on the
range axis its FWHM is the resolving distance ``ΔR = c·pulse_length / 2`` (σ = ΔR / 2.3548). The
received waveform is the sum of the sub-rays' powers, each laid at its hit range and shaped by the
pulse. Returns closer together than ΔR cannot be separated by a detector, so sub-ray returns are
sorted by range and chained while consecutive ranges are within ΔR: each chain is one echo. Two
equal surfaces further apart than ΔR always give two waveform maxima (two Gaussians separate once
their distance exceeds 2σ = 0.85·ΔR), so every chain is a peak of the waveform. An echo's amplitude is
the waveform's value at the chain's energy-weighted mean range; echoes below the detection threshold
are dropped; the first ``max_returns`` in range order are kept (0 = no limit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..echoes import FWHM_PER_SIGMA


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
    """Echoes of P pulses of S sub-rays each.

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
