"""Waveform and pulse records, ``output.waveforms`` and ``output.pulses``: ``NAME_waveforms.npz`` and
``NAME_pulses.npz`` (README, "Waveforms and pulse records", lists their arrays).

Both are NPZ files (a zip of ``.npy`` arrays, ``numpy.load`` reads them) written with bounded memory:
each batch's rows are appended to one spool file per array beside the output; on close each array is
streamed into its zip member (NPY header with the final shape, then the spooled rows, a block at a
time) and the spools are removed. Members are deflated (level 1): waveforms are mostly zeros.
"""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

import numpy as np

from ..config.types import SPEED_OF_LIGHT
from ..scan.waveform import echo_energy, pulse_sigma
from .atomic import naming_errors
from .closing import Closing

COPY_BLOCK = 1 << 24        # bytes copied from a spool at a time
COMPRESS_LEVEL = 1


class NpzStream(Closing):
    """An NPZ whose arrays grow by rows (:meth:`append`) and are assembled on :meth:`close`; closing,
    aborting and refusing writes once closed as :class:`~.closing.Closing`.

    :param path: the output file; its spools are ``path`` + ``.KEY.spool`` until close.
    :param arrays: ``{key: (dtype, row shape)}``, in file order.
    :param scalars: ``{key: value}`` 0-d arrays written as they are.
    """

    def __init__(self, path, arrays: dict, scalars: dict | None = None):
        self.path = Path(path)
        self.arrays = {k: (np.dtype(d), tuple(shape)) for k, (d, shape) in arrays.items()}
        self.scalars = dict(scalars or {})
        self.rows = dict.fromkeys(self.arrays, 0)
        self._spools = {}
        for key in self.arrays:
            spool = self._spool_path(key)
            with naming_errors(spool):
                self._spools[key] = open(spool, "wb")   # noqa: SIM115 (closed in close/abort)

    def _spool_path(self, key: str) -> Path:
        return self.path.with_name(f"{self.path.name}.{key}.spool")

    def append(self, **columns) -> None:
        """Append rows to some arrays (each ``(n, *row shape)``, cast to the array's dtype)."""
        self._refuse_if_closed()
        for key, value in columns.items():
            dtype, shape = self.arrays[key]
            value = np.ascontiguousarray(value, dtype)
            if value.shape[1:] != shape:
                raise ValueError(f"{key}: rows of shape {value.shape[1:]}, expected {shape}")
            with naming_errors(self.path):      # a failing write names no file: name the one it is for
                self._spools[key].write(value.tobytes())
            self.rows[key] += len(value)

    def _finish(self) -> None:
        try:
            for handle in self._spools.values():
                handle.close()
            with naming_errors(self.path), zipfile.ZipFile(self.path, "w", zipfile.ZIP_DEFLATED,
                                                           compresslevel=COMPRESS_LEVEL) as archive:
                for key, value in self.scalars.items():
                    with archive.open(key + ".npy", "w") as member:
                        np.lib.format.write_array(member, np.asarray(value), allow_pickle=False)
                for key, (dtype, shape) in self.arrays.items():
                    with archive.open(key + ".npy", "w", force_zip64=True) as member:
                        header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                                  "shape": (self.rows[key], *shape)}
                        np.lib.format.write_array_header_2_0(member, header)
                        with open(self._spool_path(key), "rb") as spool:
                            shutil.copyfileobj(spool, member, COPY_BLOCK)
        finally:
            self._remove_spools()

    def _discard(self) -> None:
        for handle in self._spools.values():
            handle.close()
        self._remove_spools()

    def _remove_spools(self) -> None:
        for key in self.arrays:
            self._spool_path(key).unlink(missing_ok=True)


class PulseRecordWriter(Closing):
    """Receives each scan batch's :class:`~mitsuforest.scan.waveform.PulseBatch` (:meth:`add`) and writes
    ``NAME_waveforms.npz`` (``output.waveforms``) and ``NAME_pulses.npz`` (``output.pulses``).

    Coordinates are georeferenced (local frame plus ``origin.offset``, float64); directions are the
    same in both frames. They are the true beam's: with ``survey.navigation_errors`` the points are
    placed with the believed trajectory instead.

    Closing, aborting and refusing batches once closed as :class:`~.closing.Closing`.

    :param staging: the render's :class:`~mitsuforest.write.Staging`.
    :param scene: the :class:`~mitsuforest.config.types.Scene`.
    """

    def __init__(self, staging, scene):
        self.offset = np.asarray(scene.origin.offset, np.float64)
        sensor = scene.sensor
        self.sampling = sensor.waveform
        self.sigma = pulse_sigma(sensor.resolving_distance)
        self.waveforms = self.pulses = None
        beam = {"pulse_id": ("<u8", ()), "gps_time": ("<f8", ()), "scan_angle": ("<f4", ()),
                "point_source_id": ("<u2", ()), "origin": ("<f8", (3,)), "direction": ("<f4", (3,))}
        if scene.output.waveforms:
            sampling = self.sampling
            self.waveforms = NpzStream(staging.file("_waveforms.npz"), {
                **beam, "echoes": ("<u2", ()), "first_bin": ("<u4", ()), "complete": ("|b1", ()),
                "samples": ("<f4", (sampling.samples,)),
                "echo_pulse": ("<u8", ()), "echo_return_number": ("u1", ()), "echo_range": ("<f4", ()),
                "echo_time": ("<f8", ()), "echo_amplitude": ("<f4", ()), "echo_energy": ("<f4", ())},
                {"bin_size": np.float64(sampling.bin_size), "bin_range": np.float64(sampling.bin_range),
                 "pulse_sigma": np.float64(self.sigma)})
        if scene.output.pulses:
            self.pulses = NpzStream(staging.file("_pulses.npz"), {**beam, "echoes": ("<u2", ())})
        self.incomplete = 0    # waveforms whose returns reach out of the window (not complete)
        self.with_echoes = 0   # fired pulses with an echo

    def add(self, batch) -> None:
        self._refuse_if_closed()
        if self.waveforms is not None:
            self._add_waveforms(batch)
        if self.pulses is not None:
            fired = batch.fired
            counts = batch.echo_counts(fired["pulse_id"])
            self.pulses.append(**self._beam(fired, batch.source_id), echoes=counts)
            self.with_echoes += int(np.count_nonzero(counts))

    def _beam(self, pulses: dict, source_id: int) -> dict:
        return {"pulse_id": pulses["pulse_id"], "gps_time": pulses["gps_time"],
                "scan_angle": np.rad2deg(pulses["scan_angle"]),
                "point_source_id": np.full(len(pulses["pulse_id"]), source_id),
                "origin": np.asarray(pulses["origin"], np.float64) + self.offset, "direction": pulses["direction"]}

    def _add_waveforms(self, batch) -> None:
        pulses = batch.cast
        first_bin, samples, complete = pulses["first_bin"], pulses["samples"], pulses["complete"]
        echoes = batch.echoes
        written = self.waveforms.rows["samples"]
        self.waveforms.append(**self._beam(pulses, batch.source_id), echoes=batch.echo_counts(pulses["pulse_id"]),
                              first_bin=first_bin, complete=complete, samples=samples)
        row = np.searchsorted(pulses["pulse_id"], echoes["pulse_id"]) + written
        self.waveforms.append(echo_pulse=row, echo_return_number=np.minimum(echoes["return_number"], 255),
                              echo_range=echoes["range"],
                              echo_time=2.0 * echoes["range"].astype(np.float64) / SPEED_OF_LIGHT,
                              echo_amplitude=echoes["amplitude"], echo_energy=echo_energy(echoes["energy"], self.sigma))
        self.incomplete += int(np.count_nonzero(~complete))

    def _finish(self) -> None:
        for stream in (self.waveforms, self.pulses):
            if stream is not None:
                stream.close()

    def _discard(self) -> None:
        for stream in (self.waveforms, self.pulses):
            if stream is not None:
                stream.abort()

    def statistics(self) -> dict:
        """The manifest's ``waveforms`` and ``pulse_records`` entries."""
        out = {}
        if self.waveforms is not None:
            out["waveforms"] = {"file": self.waveforms.path.name, "pulses": self.waveforms.rows["samples"],
                                "echoes": self.waveforms.rows["echo_pulse"],
                                "bin_size_s": self.sampling.bin_size, "samples": self.sampling.samples,
                                "bin_range_m": self.sampling.bin_range, "pulse_sigma_m": self.sigma,
                                "incomplete": self.incomplete}
        if self.pulses is not None:
            fired = self.pulses.rows["pulse_id"]
            out["pulse_records"] = {"file": self.pulses.path.name, "fired": fired,
                                    "with_echoes": self.with_echoes, "without_echoes": fired - self.with_echoes}
        return out
