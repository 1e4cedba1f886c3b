"""The point writer's threads and worker processes: the same bytes with one thread, with several and
with processes, LAZ and PCD that read back as the points written, LAS records as laspy makes them, and
the thread and process counts' settings; the scan's read-ahead."""

import io
import pickle
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

import laspy
import numpy as np
import numpy.lib.recfunctions  # noqa: F401 (np.lib.recfunctions)
import pytest
from conftest import ROOT
from helpers import settled

from mitsuforest.errors import UserError
from mitsuforest.scan import POINT_DTYPE, READ_AHEAD_VARIABLE
from mitsuforest.threads import THREADS_VARIABLE, ReadAhead, row_ranges, writer_threads
from mitsuforest.write import PointWriter, Staging, read_pcd
from mitsuforest.write.processes import PROCESSES_VARIABLE, fits_processes, writer_processes
from mitsuforest.write.las import ASPRS_CODE, COORDINATE_SCALE, LasStream, las_header, las_records

DEFAULT_GAIN = 1e6   # the default intensity mapping: counts per unit of amplitude

OFFSET = (500000.123, 6100000.456, 12.5)
BATCHES = (70_000, 1, 0, 123_457, 40_000, 90_001)   # parts of several sizes, an empty batch, a batch of one


def _scene(offset, formats=("pcd", "las", "laz")):
    from mitsuforest.config import load_scene
    return load_scene(ROOT / "scenes" / "demo.yaml").with_({"origin.offset": list(offset),
                                                            "output.formats": list(formats)})


def _batches(seed=3) -> list[np.ndarray]:
    """Points over the demo's 20 m plot with every field varied (returns above 15 included)."""
    rng = np.random.default_rng(seed)
    out, t = [], 0.0
    for n in BATCHES:
        p = np.zeros(n, POINT_DTYPE)
        p["x"], p["y"] = rng.uniform(-1, 21, n), rng.uniform(-1, 21, n)
        p["z"] = rng.uniform(-0.5, 30, n)
        p["classification"] = rng.integers(1, 9, n)
        p["treeid"], p["instance"] = rng.integers(0, 12, n), rng.integers(0, 50, n)
        p["object_id"] = rng.integers(0, 9e5, n)
        p["number_of_returns"] = rng.integers(1, 20, n)
        p["return_number"] = np.minimum(rng.integers(1, 20, n), p["number_of_returns"])
        p["intensity"] = rng.uniform(0, 0.08, n).astype(np.float32)
        p["gps_time"] = t + np.cumsum(rng.uniform(0, 5e-6, n))
        t = p["gps_time"][-1] if n else t
        p["scan_angle"] = rng.uniform(-60, 60, n)
        p["pulse_id"], p["range"], p["species"] = np.arange(n), rng.uniform(1, 60, n), rng.integers(0, 5, n)
        p["reflectance"] = rng.uniform(-30, 5, n)
        p["point_source_id"] = rng.integers(1, 9, n)
        out.append(p)
    return out


def _write(tmp_path, name, scene, threads) -> tuple[dict, PointWriter]:
    staging = Staging(tmp_path / name, scene.name)
    writer = PointWriter(staging, scene, keep=True, threads=threads)
    for batch in _batches():
        writer.add(batch)
    writer.close()
    return {p.suffix: p.read_bytes() for p in staging.path.iterdir()}, writer


@pytest.mark.parametrize("offset, threads", [((0.0, 0.0, 0.0), 4), (OFFSET, 2), (OFFSET, 4)])
def test_one_thread_and_many_write_the_same_bytes_and_statistics(tmp_path, offset, threads):
    """With 2 threads the LAZ stream hands lazrs 150,000 points twice, each time holding back the
    rest of a chunk; with 4, 200,000 once."""
    scene = _scene(offset)
    serial, one = _write(tmp_path, "one", scene, threads=1)
    parallel, many = _write(tmp_path, "many", scene, threads=threads)
    assert set(serial) == {".pcd", ".las", ".laz"}
    assert all(serial[k] == parallel[k] for k in serial)
    assert one.statistics() == many.statistics()
    assert np.array_equal(one.top.top, many.top.top) and np.array_equal(one.top.cls, many.top.cls)
    assert np.array_equal(one.side.points(), many.side.points())
    assert np.array_equal(one.counts.by_height, many.counts.by_height)
    assert np.array_equal(one.counts.by_return, many.counts.by_return)
    assert one.count == many.count == sum(BATCHES)


def _write_apart(tmp_path, name, scene, processes, batches=None) -> tuple[dict, PointWriter]:
    staging = Staging(tmp_path / name, scene.name)
    writer = PointWriter(staging, scene, threads=1, processes=processes)
    for batch in _batches() if batches is None else batches:
        writer.add(batch)
    writer.close()
    return {p.suffix: p.read_bytes() for p in staging.path.iterdir()}, writer


@pytest.mark.parametrize("offset, formats", [((0.0, 0.0, 0.0), ("pcd", "laz")), (OFFSET, ("pcd", "laz")),
                                             (OFFSET, ("laz",)), (OFFSET, ("pcd",))])
def test_worker_processes_write_the_bytes_and_statistics_of_one_thread(tmp_path, offset, formats):
    """Two worker processes take parts of two LAZ chunks (the batches' rows past a whole chunk held for
    the next, the file's last part short): the files and every statistic of one thread's writer, the top
    view's pixels merged from the parts included."""
    scene = _scene(offset, formats)
    serial, one = _write_apart(tmp_path, "one", scene, processes=0)
    apart, many = _write_apart(tmp_path, "apart", scene, processes=2)
    assert one._parts is None and many._parts is not None
    assert set(serial) == {"." + f for f in formats} and serial == apart
    assert one.statistics() == many.statistics()
    assert np.array_equal(one.top.top, many.top.top) and np.array_equal(one.top.cls, many.top.cls)
    assert np.array_equal(one.side.points(), many.side.points())
    assert np.array_equal(one.counts.by_height, many.counts.by_height)
    assert np.array_equal(one.counts.by_return, many.counts.by_return)
    assert many.count == sum(BATCHES)
    if ".laz" in serial:
        las = laspy.read(io.BytesIO(apart[".laz"]))
        assert las.header.point_count == sum(BATCHES)
        assert las.header.number_of_points_by_return[0] == sum((b["return_number"] == 1).sum() for b in _batches())
        assert np.allclose(las.x, np.concatenate(_batches())["x"] + offset[0], atol=1e-4)


@pytest.mark.parametrize("threads, processes", [(1, 0), (2, 0), (1, 2)])
def test_las_intensity_is_the_sensors_mapping_with_threads_and_processes(tmp_path, threads, processes):
    """A sensor's own intensity mapping (RIEGL's reflectance in dB) reaches the LAS and LAZ records,
    by one thread, several or the worker processes: the threads once wrote amplitude x 1e6 whatever
    the sensor said, while the header's note and the processes used the sensor's mapping."""
    import dataclasses as dc
    from mitsuforest.config.types import IntensityMapping
    from mitsuforest.scan.radiometry import RIEGL_DB_MAP, intensity_counts
    scene = _scene(OFFSET, ("pcd", "las", "laz") if processes == 0 else ("pcd", "laz"))
    mapping = IntensityMapping(**RIEGL_DB_MAP)
    scene = scene.with_({"sensor": dc.replace(scene.sensor, intensity=mapping)})
    staging = Staging(tmp_path / "w", scene.name)
    writer = PointWriter(staging, scene, threads=threads, processes=processes)
    for batch in _batches():
        writer.add(batch)
    writer.close()
    points = np.concatenate(_batches())
    expected = intensity_counts(points["intensity"], points["reflectance"], mapping)
    assert 20_000 < np.median(expected) < 65535          # counts of -25 to +5 dB, not amplitude x 1e6
    for suffix in ("las", "laz") if processes == 0 else ("laz",):
        las = laspy.read(staging.path / f"{scene.name}.{suffix}")
        assert np.array_equal(np.asarray(las.intensity), expected), suffix


def test_parts_of_a_large_plot_come_back_through_shared_memory_with_the_bytes_of_one_thread(tmp_path,
                                                                                           monkeypatch):
    """Over a 200 m plot the side tile keeps a few points, and every part's results fit in its rows of
    the batch: batches of up to eight parts, each part read from its own place in the slot."""
    from mitsuforest.write import processes
    routes, taken_back = [], processes.taken_back
    monkeypatch.setattr(processes, "taken_back",
                        lambda result, batch: routes.append(type(result)) or taken_back(result, batch))
    batches = [np.concatenate(_batches()[:2] * 3), *_batches(seed=4)]
    for batch in batches:
        batch["x"] *= 10
        batch["y"] *= 10
    scene = _scene(OFFSET, ("pcd", "laz")).with_({"area.size": [200, 200]})
    serial, one = _write_apart(tmp_path, "one", scene, processes=0, batches=batches)
    apart, many = _write_apart(tmp_path, "apart", scene, processes=2, batches=batches)
    assert serial == apart and one.statistics() == many.statistics()
    assert np.array_equal(one.top.top, many.top.top) and np.array_equal(one.side.points(), many.side.points())
    assert routes.count(tuple) == len(routes) == 7    # the first batch two parts of 100,000 rows in one slot


def test_a_parts_results_come_back_in_its_rows_of_shared_memory_or_else_through_the_pipe(tmp_path):
    """A worker pickles a part's results over its own rows of the batch file, which the writing process
    reads there; results larger than those rows are returned as they are, and the file is left alone."""
    from mitsuforest.write.processes import PartResult, placed, taken_back
    rng = np.random.default_rng(5)
    part = PartResult(3, (np.arange(256), rng.random((4, 3))), (np.arange(10), rng.random(10)),
                      (rng.bytes(5000), [(50_000, 5000)], None))
    batch = tmp_path / "batch"
    batch.write_bytes(b"\x01" * 30_000)
    where = placed(part, str(batch), 20_000, 10_000)
    mapped = np.memmap(batch, np.uint8, "r")
    assert isinstance(where, tuple) and where[0] == 20_000 and 5000 < where[1] <= 10_000
    assert mapped[:20_000].min() == 1 and mapped[20_000 + where[1]:].min() == 1          # no byte outside
    back = taken_back(where, mapped)
    assert back.rows == 3 and back.laz[0] == part.laz[0] and back.laz[1] == part.laz[1]
    assert all(np.array_equal(a, b) for a, b in zip(back.tallies + back.top, part.tallies + part.top))
    before = batch.read_bytes()
    assert placed(part, str(batch), 0, 4000) is part and batch.read_bytes() == before   # too little room
    assert taken_back(part, mapped) is part


def test_top_view_merged_from_parts_is_the_view_of_all_points():
    """Pixels hit by many points at equal heights: the class of the last point at the top, whichever way
    the points are cut into parts."""
    from mitsuforest.write.quicklook import TopView
    rng = np.random.default_rng(2)
    p = np.zeros(20_000, POINT_DTYPE)
    p["x"], p["y"] = rng.uniform(0, 2, 20_000), rng.uniform(0, 2, 20_000)
    p["z"] = rng.integers(0, 4, 20_000)                          # many ties
    p["classification"] = rng.integers(1, 9, 20_000)
    whole, parts = TopView((2, 2)), TopView((2, 2))
    whole.add(p)
    for cut in np.split(p, [3, 7000, 7001, 15_000]):
        parts.merge(parts.part(cut))
    assert np.array_equal(whole.top, parts.top) and np.array_equal(whole.cls, parts.cls)


def test_a_part_that_fails_in_a_worker_fails_the_writer_and_leaves_no_shared_memory(tmp_path):
    """A coordinate that LAS cannot hold raises the threads' error from the worker, once no other part
    of its batch is still being written (six parts: the first fails, the others compress); abort removes
    the batches' shared files, and the pool serves the next writer."""
    import glob
    scene = _scene(OFFSET, ("pcd", "laz"))
    far = np.concatenate(_batches()[:1] * 9)[:600_000]
    far["x"][:10] = 1e9
    others = set(glob.glob("/dev/shm/mitsuforest-writer-*"))     # other renders' (or a failed test's)
    writer = PointWriter(Staging(tmp_path / "far", scene.name), scene, threads=1, processes=2)
    writer.add(far[:0])
    submitted, submit = [], writer._parts.pool.submit
    writer._parts.pool.submit = lambda *args: submitted.append(submit(*args)) or submitted[-1]
    with pytest.raises(OverflowError, match="do not fit"):
        writer.add(far)
        writer.close()
    assert len(submitted) == 6 and all(task.done() for task in submitted)
    writer.abort()
    assert not writer._parts._folder.exists()
    assert set(glob.glob("/dev/shm/mitsuforest-writer-*")) <= others
    again, _ = _write_apart(tmp_path, "again", scene, processes=2)
    assert again == _write_apart(tmp_path, "one", scene, processes=0)[0]


def test_worker_processes_given_no_points_write_empty_files_and_leave_no_shared_memory(tmp_path):
    """A render of no points: the PCD's header made on close no longer starts the batches' shared folder
    after the parts were closed (it stayed in /dev/shm)."""
    import glob
    others = set(glob.glob("/dev/shm/mitsuforest-writer-*"))
    scene = _scene(OFFSET, ("pcd", "laz"))
    staging = Staging(tmp_path / "none", scene.name)
    writer = PointWriter(staging, scene, threads=1, processes=2)
    writer.close()
    assert set(glob.glob("/dev/shm/mitsuforest-writer-*")) <= others
    assert read_pcd(staging.file(".pcd")).shape == (0,) and laspy.read(staging.file(".laz")).header.point_count == 0


def test_a_script_without_a_main_guard_runs_once_beside_the_writer_processes(tmp_path):
    """Spawned workers would run the parent's main module first; they start while it is hidden."""
    script = tmp_path / "plain.py"
    script.write_text(
        "import numpy as np\nprint('top level ran')\n"
        "from mitsuforest.config import load_scene\nfrom mitsuforest.scan import POINT_DTYPE\n"
        "from mitsuforest.write import PointWriter, Staging\n"
        f"scene = load_scene({str(ROOT / 'scenes' / 'demo.yaml')!r})\n"
        "p = np.zeros(120_000, POINT_DTYPE)\np['x'] = np.arange(120_000) * 1e-4\np['return_number'] = 1\n"
        "w = PointWriter(Staging('out', scene.name), scene, processes=2)\nw.add(p)\nw.close()\n"
        "print(w.count, w._parts is not None)\n")
    run = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.count("top level ran") == 1 and "120000 True" in run.stdout


def test_writer_processes_from_eight_cores_or_the_variable(monkeypatch):
    monkeypatch.delenv(PROCESSES_VARIABLE, raising=False)
    assert writer_processes(2) == 0 and writer_processes(7) == 0 and writer_processes(16) == 15
    monkeypatch.setenv(PROCESSES_VARIABLE, "0")
    assert writer_processes(16) == 0
    monkeypatch.setenv(PROCESSES_VARIABLE, "3")
    assert writer_processes(2) == 3
    for bad in ("many", "-1", "1.5"):
        monkeypatch.setenv(PROCESSES_VARIABLE, bad)
        with pytest.raises(UserError, match=f"{PROCESSES_VARIABLE}: must be a whole number >= 0, got '{bad}'"):
            writer_processes(2)


@pytest.mark.parametrize("threads", [3, None])
def test_a_dataset_worker_writes_with_threads_whether_or_not_threads_are_given(monkeypatch, threads):
    """README: "a dataset's workers use none unless it is set, since the plots already share the cores",
    also on a scheduler's workers without ``--threads`` (``threads`` None), on a machine of 16 cores."""
    import os

    from mitsuforest.dataset.tasks import set_threads
    for name in (PROCESSES_VARIABLE, THREADS_VARIABLE):
        monkeypatch.setenv(name, "1")       # so that the test's end removes what set_threads sets
        monkeypatch.delenv(name)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(16)), raising=False)
    monkeypatch.setattr("drjit.set_thread_count", lambda n: None)
    set_threads(threads)
    assert writer_processes() == 0
    assert writer_threads() == (threads or 16)


def test_outputs_the_processes_do_not_write_keep_the_threads(tmp_path):
    """LAS, COPC, an output profile or points kept in memory: the threads write them."""
    for formats, keep in ((("pcd", "las"), False), (("pcd", "laz"), True)):
        writer = PointWriter(Staging(tmp_path / "-".join(formats), "demo"), _scene(OFFSET, formats), keep=keep,
                             processes=2)
        assert writer._processes == 0
        writer.abort()
    assert not fits_processes(_scene(OFFSET, ("laz", "copc"))) and fits_processes(_scene(OFFSET, ("laz",)))
    scene = _scene(OFFSET, ("laz",)).with_({"output.profile": "for-instance"})
    writer = PointWriter(Staging(tmp_path / "profile", "demo"), scene, processes=2)
    assert writer._processes == 0
    writer.abort()


def test_files_read_back_as_the_points_written(tmp_path):
    """The LAZ (and LAS) read by laspy and the PCD read back hold the georeferenced points: x, y, z to
    the 0.1 mm grid, labels and times exact."""
    files, writer = _write(tmp_path, "out", _scene(OFFSET), threads=4)
    points = writer.points
    geo = np.concatenate(_batches())
    for axis, o in zip("xyz", OFFSET):
        geo[axis] += o
    assert points.dtype.names == (*geo.dtype.names, "height_above_ground")   # the writer adds it
    assert all(np.array_equal(points[name], geo[name]) for name in geo.dtype.names)
    pcd = read_pcd(next((tmp_path / "out").glob(".*/demo.pcd")))
    assert all(np.array_equal(pcd[name], geo[name]) for name in geo.dtype.names)   # float64 x, y, z with an offset
    for suffix in (".laz", ".las"):
        las = laspy.read(next((tmp_path / "out").glob(f".*/demo{suffix}")))
        assert las.header.point_count == len(geo)
        for axis in "xyz":
            assert np.abs(np.asarray(las[axis]) - geo[axis]).max() <= COORDINATE_SCALE / 2 + 1e-9
        assert np.array_equal(las.label, geo["classification"])
        assert np.array_equal(las.classification, [ASPRS_CODE[c] for c in geo["classification"]])
        assert np.array_equal(las.return_number, np.minimum(geo["return_number"], 15))
        assert np.array_equal(las.number_of_returns, np.minimum(geo["number_of_returns"], 15))
        assert np.array_equal(las.gps_time, geo["gps_time"])
        assert np.array_equal(las.amplitude, geo["intensity"])
        assert np.array_equal(las.intensity, np.minimum(np.round(DEFAULT_GAIN * geo["intensity"].astype(float)), 65535))
        for name in ("treeid", "instance", "object_id", "species", "reflectance", "point_source_id"):
            assert np.array_equal(las[name], geo[name]), name
        assert list(las.header.number_of_points_by_return[:3]) == [
            int(np.sum(np.minimum(geo["return_number"], 15) == k)) for k in (1, 2, 3)]


def test_las_records_are_those_laspy_makes(tmp_path):
    """The records packed with numpy are byte for byte those laspy's LasData makes of the same points."""
    points = np.concatenate(_batches())[:20000]
    for axis, o in zip("xyz", OFFSET):
        points[axis] += o
    header = las_header(OFFSET)
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(len(points), header=header))
    las.x, las.y, las.z = points["x"], points["y"], points["z"]
    las.classification = [ASPRS_CODE[c] for c in points["classification"]]
    las.return_number = np.minimum(points["return_number"], 15)
    las.number_of_returns = np.minimum(points["number_of_returns"], 15)
    las.intensity = np.clip(np.round(DEFAULT_GAIN * points["intensity"].astype(float)), 0, 65535).astype(np.uint16)
    las.gps_time = points["gps_time"]
    las.scan_angle = np.round(points["scan_angle"] / 0.006).astype(np.int16)
    las.label, las.amplitude = points["classification"], points["intensity"]
    for name in ("treeid", "instance", "object_id", "species", "reflectance", "point_source_id"):
        las[name] = points[name]
    las.height_above_ground = np.full(len(points), np.nan, np.float32)   # not among the points' fields: unknown
    assert las_records(header, points).tobytes() == las.points.array.tobytes()
    with_height = np.lib.recfunctions.append_fields(points, "height_above_ground", points["z"] - 2.0, "<f4",
                                                    usemask=False)
    las.height_above_ground = with_height["height_above_ground"]
    assert las_records(header, with_height).tobytes() == las.points.array.tobytes()


def test_las_stream_closes_on_error_and_refuses_writes_once_closed(tmp_path):
    points = _batches()[0]
    with LasStream(tmp_path / "a.laz", (0, 0, 0)) as stream:
        stream.write(points)
    assert laspy.read(tmp_path / "a.laz").header.point_count == len(points)
    with pytest.raises(ValueError, match="closed"):
        stream.write(points)
    stream.close()                                             # a second close does nothing
    with pytest.raises(RuntimeError, match="stop"):
        with LasStream(tmp_path / "b.laz", (0, 0, 0)) as broken:
            broken.write(points)
            raise RuntimeError("stop")
    assert broken.closed and broken._writer.dest.closed
    with pytest.raises(ValueError, match="closed"):
        broken.write(points)


def _stream(kind, path):
    """(a stream of ``kind`` writing ``path``, its write method, a batch for it)."""
    from mitsuforest.write.copc import CopcStream
    from mitsuforest.write.output_profiles import ForestFormer3DStream, TreeLearnStream
    from mitsuforest.write.waveforms import NpzStream
    scanned = _batches()[0][:1000]
    points = np.lib.recfunctions.append_fields(scanned, "height_above_ground", scanned["z"], "<f4", usemask=False)
    if kind == "point writer":
        scene = _scene(OFFSET, ("pcd", "laz"))
        writer = PointWriter(Staging(path, scene.name), scene, threads=2, processes=0)
        return writer, writer.add, _batches()[0][:1000]
    if kind == "npz":
        stream = NpzStream(path / "t.npz", {"z": ("<f4", ())})
        return stream, lambda z: stream.append(z=z), points["z"]
    if kind == "copc":
        pytest.importorskip("copclib", reason="copclib (the test extra) writes COPC")
    made = {"copc": CopcStream, "ff3d": ForestFormer3DStream, "treelearn": TreeLearnStream}[kind]
    stream = made(path / f"t.{kind}", (0.0, 0.0, 0.0), None, *(() if kind == "copc" else (np.zeros(0),)))
    return stream, stream.write, points


@pytest.mark.parametrize("kind", ["point writer", "copc", "npz", "ff3d", "treelearn"])
def test_every_stream_closes_on_error_and_refuses_writes_once_closed(tmp_path, kind, monkeypatch):
    """As laspy's writer (and our LAS stream, above): closed at the end of its block, aborted after an
    error in it (no spool left), writes refused once closed either way, a second close a no-op."""
    for folder in ("ok", "broken"):
        (tmp_path / folder).mkdir()
    ok, write, batch = _stream(kind, tmp_path / "ok")
    with ok:
        write(batch)
    files = sorted(p.name for p in (tmp_path / "ok").rglob("*") if p.is_file())
    assert files and not [f for f in files if f.endswith(".spool")]
    with pytest.raises(ValueError, match=f"write to a closed {type(ok).__name__}"):
        write(batch)
    ok.close()
    assert sorted(p.name for p in (tmp_path / "ok").rglob("*") if p.is_file()) == files
    broken, write, batch = _stream(kind, tmp_path / "broken")
    monkeypatch.setattr(type(broken), "_finish", lambda self: pytest.fail("a failed block finished its file"))
    with pytest.raises(RuntimeError, match="stop"):
        with broken:
            write(batch)
            raise RuntimeError("stop")
    assert broken.closed and not list((tmp_path / "broken").rglob("*.spool"))
    with pytest.raises(ValueError, match=f"write to a closed {type(broken).__name__}"):
        write(batch)


def test_thread_count_follows_the_cores_or_the_variable(monkeypatch):
    import os
    monkeypatch.delenv(THREADS_VARIABLE, raising=False)
    assert writer_threads() == len(os.sched_getaffinity(0))
    monkeypatch.setenv(THREADS_VARIABLE, "3")
    assert writer_threads() == 3
    for bad in ("0", "two", "-1", "1.5"):
        monkeypatch.setenv(THREADS_VARIABLE, bad)
        with pytest.raises(UserError, match=f"{THREADS_VARIABLE}: must be a whole number >= 1, got '{bad}'"):
            writer_threads()


def test_row_ranges_cover_the_rows_once():
    assert row_ranges(0, 4) == [(0, 0)]
    assert row_ranges(100, 4) == [(0, 100)]                    # below the part size: one part
    ranges = row_ranges(1_000_003, 7, minimum=1000)
    assert len(ranges) == 7 and ranges[0][0] == 0 and ranges[-1][1] == 1_000_003
    assert all(a[1] == b[0] for a, b in zip(ranges, ranges[1:]))
    assert max(b - a for a, b in ranges) - min(b - a for a, b in ranges) <= 1


def test_read_ahead_gives_the_items_in_order_and_raises_where_the_failure_came():
    def items():
        yield from range(5)
        raise OSError("disk full")
    ahead, got = ReadAhead(items()), []
    with pytest.raises(OSError, match="disk full"):
        for item in ahead:
            got.append(item)
    assert got == [0, 1, 2, 3, 4]
    assert list(ahead) == []                         # ended: it stays ended
    assert list(ReadAhead(iter(()))) == []


def test_read_ahead_makes_its_depth_ahead_stops_when_closed_and_its_thread_serves_the_next():
    made, threads = [], set()

    def items():
        for i in range(100):
            made.append(i)
            threads.add(threading.get_ident())
            yield i
    with ReadAhead(items(), depth=1) as ahead:
        assert next(ahead) == 0
        assert settled(made, 2) == [0, 1]          # the item taken, and one made ahead waiting to be taken
        assert next(ahead) == 1
        assert settled(made, 3) == [0, 1, 2]
    assert settled(made, 4, timeout=0) == [0, 1, 2]      # closed: nothing more is made
    with pytest.raises(StopIteration):
        next(ahead)
    made.clear()
    assert list(ReadAhead(items(), depth=2))[:3] == [0, 1, 2]
    assert len(threads) == 1 and threading.get_ident() not in threads     # one thread, kept, not the caller's


@pytest.mark.parametrize("variable, least, value", [(THREADS_VARIABLE, 1, "many"), (PROCESSES_VARIABLE, 0, "-1"),
                                                    (READ_AHEAD_VARIABLE, 0, "²"), (THREADS_VARIABLE, 1, "0")])
def test_a_bad_variable_is_refused_before_any_work(tmp_path, monkeypatch, capsys, variable, least, value):
    """A value that is not a whole number of at least ``least`` ('²' is a digit to ``str.isdigit``)."""
    from mitsuforest.cli import main
    monkeypatch.setenv(variable, value)
    code = main(["render", str(ROOT / "scenes" / "demo.yaml"), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err == f"mitsuforest: {variable}: must be a whole number >= {least}, got {value!r}"
    assert not (tmp_path / "out").exists()


def test_point_array_filled_by_threads_is_the_echoes(monkeypatch):
    """The scan's point array, filled by row ranges on four threads, holds each echo field in its place
    (intensity from the amplitude, the scan angle in degrees), and its hits each echo's rows; the labels
    stage, on the same threads, gathers each label from the rows it names."""
    from mitsuforest import labels, threads
    from mitsuforest.scan import tracer
    from mitsuforest.threads import Workers
    rng = np.random.default_rng(5)
    n = 150_001
    echoes = {k: rng.integers(0, 200, n).astype(t) for k, t in (
        ("object_row", np.uint32), ("triangle", np.uint32), ("number_of_returns", np.uint32),
        ("return_number", np.uint32), ("pulse_id", np.uint64))}
    echoes.update({k: rng.uniform(-50, 50, n).astype(np.float32) for k in ("x", "y", "z")})
    echoes.update({k: rng.uniform(0.1, 50, n).astype(np.float32) for k in ("range", "amplitude")})
    echoes["gps_time"], echoes["scan_angle"] = rng.uniform(0, 1e3, n), rng.uniform(-1, 1, n).astype(np.float32)
    workers = Workers(4)
    monkeypatch.setattr(threads, "shared_workers", lambda: workers)     # on_row_ranges' threads
    points, hits = tracer.PulseTracer._points(echoes)
    for key in ("x", "y", "z", "number_of_returns", "return_number", "gps_time", "pulse_id", "range"):
        assert np.array_equal(points[key], echoes[key].astype(points.dtype[key])), key
    assert np.array_equal(points["intensity"], echoes["amplitude"])
    assert np.array_equal(points["scan_angle"], np.rad2deg(echoes["scan_angle"]))
    assert np.array_equal(hits["object_row"], echoes["object_row"]) and np.array_equal(hits["triangle"], echoes["triangle"])
    assert not points["instance"].any() and not points["classification"].any()       # the scan labels nothing
    located = {key: rng.integers(1, 250, 200).astype(t) for key, t in (
        ("object_instance", np.uint32), ("object_id_base", np.uint32), ("object_treeid", np.uint16),
        ("object_species", np.uint8), ("triangle_component", np.uint16), ("triangle_class", np.uint8))}
    labels.label_points(points, hits, SimpleNamespace(located=located))
    workers.close()
    obj, tri = echoes["object_row"], echoes["triangle"]
    assert np.array_equal(points["instance"], located["object_instance"][obj])
    assert np.array_equal(points["treeid"], located["object_treeid"][obj])
    assert np.array_equal(points["species"], located["object_species"][obj])
    assert np.array_equal(points["object_id"], located["object_id_base"][obj] + located["triangle_component"][tri])
    assert np.array_equal(points["classification"], located["triangle_class"][tri])


def test_a_render_written_by_worker_processes_is_the_render_written_by_threads(tmp_path_factory, variant,
                                                                                 monkeypatch):
    """The demo scanned along one leg and written with two worker processes (its four pictures drawn
    in them too, the workers readied for them as on a GPU) and with the threads: every file the same
    bytes, the manifest but for paths and times."""
    import json

    from conftest import _demo_scene

    from mitsuforest import survey
    from mitsuforest.pipeline import render
    monkeypatch.setattr(survey, "scans_off_host", lambda prepared: True)
    files = {}
    for processes in ("0", "2"):
        monkeypatch.setenv(PROCESSES_VARIABLE, processes)
        result = render(_demo_scene(tmp_path_factory, variant), progress=False, log=lambda *_: None)
        files[processes] = {p.name: p.read_bytes() for p in result.files}
    threads, apart = files["0"], files["2"]
    assert len(threads) == 11 and threads.keys() == apart.keys()
    assert all(threads[name] == apart[name] for name in threads if not name.endswith("_manifest.json"))
    manifests = [json.loads(f["demo_manifest.json"]) for f in (threads, apart)]
    for manifest in manifests:
        manifest.pop("timings_s"), manifest["scene"]["output"].pop("dir")
    assert manifests[0] == manifests[1] and manifests[0]["points"] > 10_000


def test_a_worker_readies_itself_for_the_pictures_on_its_first_part_and_draws_once_ready(tmp_path, monkeypatch):
    """A writer made with ``warm_pictures`` hands its workers a PartWork that says so; a worker starts
    readying itself (once a process) when it first reads it, and a picture drawn there waits for that."""
    from mitsuforest.write import figures, processes
    events = []

    def slow_warm_up():
        time.sleep(0.2)
        events.append("warm")

    monkeypatch.setattr(figures, "warm_up", slow_warm_up)
    monkeypatch.setattr(processes, "_WARMING", [])
    monkeypatch.setattr(processes, "_WORKS", processes.collections.OrderedDict())
    scene = _scene(OFFSET, ("pcd", "laz"))
    for warm in (False, True):
        writer = PointWriter(Staging(tmp_path / str(warm), scene.name), scene, threads=1, warm_pictures=warm)
        writer.add(_batches()[0][:0])              # the PCD header: where the workers' records begin
        work = writer._part_work()
        assert work.warm_pictures is warm
        path = tmp_path / f"work-{warm}.pickle"
        path.write_bytes(pickle.dumps(work))
        rows = _batches()[0][:1000]
        slot = tmp_path / f"slot-{warm}"
        slot.write_bytes(rows.tobytes())
        part = processes.write_part(str(path), str(slot), rows.dtype, 0, len(rows), 0)
        assert part.rows == len(rows)
        assert len(processes._WARMING) == int(warm)
        writer.abort()
    processes.start_warming()                    # once a process
    assert len(processes._WARMING) == 1
    processes.draw_picture(lambda path, *inputs: events.append(("drawn", path, inputs)), "a.png", 1, 2)
    assert events == ["warm", ("drawn", "a.png", (1, 2))]
    for loaded in processes._WORKS.values():     # their PCD files' descriptors
        loaded.close()


def test_only_a_scan_off_the_host_readies_the_workers_for_the_pictures():
    from mitsuforest.survey import scans_off_host
    assert scans_off_host(SimpleNamespace(scan_scene=SimpleNamespace(variant="cuda_ad_mono")))
    assert not scans_off_host(SimpleNamespace(scan_scene=SimpleNamespace(variant="llvm_ad_mono")))


def test_warm_up_leaves_the_pictures_as_they_were(tmp_path):
    """The pictures drawn after :func:`~mitsuforest.write.figures.warm_up` in a fresh process are those
    drawn cold in another."""
    code = ("import sys, numpy as np\n"
            "from mitsuforest.write import figures\n"
            "from mitsuforest.write.profile import ReturnCounts\n"
            "if sys.argv[2] == 'warm': figures.warm_up()\n"
            "counts = ReturnCounts(None, (20.0, 20.0))\n"
            "p = np.zeros(3, [(f, 'f4') for f in 'xyz'] + [('classification', 'u1'), ('return_number', 'u1')])\n"
            "p['z'] = [1, 5, 9]; p['classification'] = [2, 4, 5]; p['return_number'] = 1\n"
            "counts.add(p)\n"
            "figures.write_returns_figure(sys.argv[1] + '/returns.png', np.array([0, 3]), counts)\n"
            "figures.write_profile_figure(sys.argv[1] + '/profile.png', counts)\n")
    drawn = {}
    for how in ("cold", "warm"):
        (tmp_path / how).mkdir()
        subprocess.run([sys.executable, "-c", code, str(tmp_path / how), how], cwd=ROOT, check=True)
        drawn[how] = {name: (tmp_path / how / name).read_bytes() for name in ("returns.png", "profile.png")}
    assert drawn["cold"] == drawn["warm"] and len(drawn["cold"]["profile.png"]) > 1000
