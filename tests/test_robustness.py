"""Robustness and interoperability: a best-effort model cache, staging folders that leave concurrent
renders alone, and a CRS that LAS readers understand."""

import logging
import os
import socket
import subprocess
from pathlib import Path

import laspy
import numpy as np
import pytest

from mitsuforest.errors import UserError
from mitsuforest.scan import POINT_DTYPE
from mitsuforest.trees import cache
from mitsuforest.trees.understory import rock_model
from mitsuforest.write import Staging
from mitsuforest.crs import crs_wkt
from mitsuforest.write.las import write_las

HOST = socket.gethostname()


class Builds:
    """A model builder that counts its calls."""

    def __init__(self):
        self.calls = 0

    def __call__(self):
        self.calls += 1
        return rock_model(seed=3, name="rock")


@pytest.fixture
def model_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("MITSUFOREST_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(cache, "_write_failed", False)
    monkeypatch.setattr(cache, "_in_memory", type(cache._in_memory)())
    return tmp_path / "cache" / "models"


def _warnings(caplog):
    return [r for r in caplog.records if r.levelno == logging.WARNING and "model cache" in r.getMessage()]


def test_cache_reuses_a_stored_model(model_cache):
    build = Builds()
    first = cache.cached("rock", {"seed": 3}, build)
    again = cache.cached("rock", {"seed": 3}, build)
    assert build.calls == 1 and len(list(model_cache.glob("rock-*.npz"))) == 1
    assert np.array_equal(first.parts[0].vertices, again.parts[0].vertices)


def test_unwritable_cache_builds_and_warns_once(tmp_path, monkeypatch, caplog):
    not_a_folder = tmp_path / "cache"
    not_a_folder.write_text("a file where the cache folder should be")
    monkeypatch.setenv("MITSUFOREST_CACHE", str(not_a_folder))
    monkeypatch.setattr(cache, "_write_failed", False)
    build = Builds()
    models = [cache.cached("rock", {"seed": s}, build) for s in (1, 2, 3)]
    assert build.calls == 3 and all(m.parts[0].faces.size for m in models)
    [warning] = _warnings(caplog)
    assert str(not_a_folder) in warning.getMessage() and "MITSUFOREST_CACHE" in warning.getMessage()


def test_full_cache_builds_warns_and_leaves_no_temporary(model_cache, monkeypatch, caplog):
    def disk_full(*_):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(cache.os, "replace", disk_full)
    build = Builds()
    assert cache.cached("rock", {"seed": 3}, build).parts and build.calls == 1
    assert "No space left" in _warnings(caplog)[0].getMessage()
    assert list(model_cache.iterdir()) == []


def _aged(path: Path, seconds_ago: float) -> None:
    """Set an entry's last read ``seconds_ago``, its modification time kept."""
    os.utime(path, ns=(int((cache.time.time() - seconds_ago) * 1e9), path.stat().st_mtime_ns))


def test_a_full_cache_drops_the_entries_read_longest_ago(model_cache, monkeypatch):
    """Entries of 40 kB under a bound of 1 MiB: the store that puts the cache past its bound removes the
    entries read longest ago until the cache holds 80 % of it; the first entry, read again just before,
    stays, and so does the one just stored. A store under the bound counts nothing."""
    monkeypatch.setattr(cache, "_cache_bytes", {})
    monkeypatch.setenv("MITSUFOREST_CACHE_SIZE", str(2 ** 20))
    values = np.zeros(5_000)

    def entry(seed):
        return model_cache / f"{cache.cache_key('crown', {'seed': seed})}.npz"

    def store(seed):
        cache.cached_arrays("crown", {"seed": seed}, ("value",), lambda: {"value": values})

    store(0)
    size = entry(0).stat().st_size
    fit = 2 ** 20 // size                                          # entries within the bound
    for seed in range(1, fit):
        store(seed)
    for seed in range(fit):
        _aged(entry(seed), 1000 - seed)                           # seed 0 read longest ago ...
    store(0)                                                      # ... but read again now
    assert all(entry(seed).exists() for seed in range(fit))
    store(fit)                                                    # past the bound
    kept = {seed for seed in range(fit + 1) if entry(seed).exists()}
    assert len(kept) * size <= cache.EVICT_TO * 2 ** 20 < (len(kept) + 1) * size
    assert kept == {0} | set(range(fit + 2 - len(kept), fit + 1))  # the ones read last, and the new one
    monkeypatch.setattr(cache, "_entries", lambda root: pytest.fail("counted under the bound"))
    store(fit + 1)


def test_one_process_evicts_at_a_time_and_an_entry_gone_meanwhile_counts_as_freed(model_cache, monkeypatch):
    """Dask workers share a cache: a process that finds another evicting (the lock held) removes nothing
    and counts again at its next store; an entry another process removed meanwhile counts as freed, so
    the evictions together leave 80 % of the bound, not an empty cache."""
    import fcntl
    monkeypatch.setattr(cache, "_cache_bytes", {})
    monkeypatch.setenv("MITSUFOREST_CACHE_SIZE", "unlimited")
    values = np.zeros(5_000)
    for seed in range(30):                                        # 1.2 MB, past the bound to come
        cache._store({"value": values}, model_cache / f"e{seed:02d}.npz")
        _aged(model_cache / f"e{seed:02d}.npz", 1000 - seed)
    monkeypatch.setenv("MITSUFOREST_CACHE_SIZE", str(2 ** 20))
    with open(model_cache / ".evict.lock", "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        cache._store({"value": values}, model_cache / "new.npz")
        assert len(list(model_cache.glob("*.npz"))) == 31 and cache._cache_bytes[model_cache.parent / "models"][0] is None
    gone = [(0, 200_000, model_cache / "removed-by-another.npz")]   # listed, then removed by another process
    entries = cache._entries
    monkeypatch.setattr(cache, "_entries", lambda root: gone + entries(root))
    cache._store({"value": values}, model_cache / "newer.npz")
    left = sum(f.stat().st_size for f in model_cache.glob("*.npz"))
    assert cache.EVICT_TO * 2 ** 20 - 200_000 - 41_000 < left <= cache.EVICT_TO * 2 ** 20
    assert (model_cache / "new.npz").exists() and (model_cache / "newer.npz").exists()


def test_a_model_held_in_memory_is_not_built_again_when_its_entry_is_evicted(model_cache):
    """Another process's eviction removes an entry this process holds in memory: the model is handed out
    from memory and stored again, not built again."""
    build = Builds()
    cache.cached("rock", {"seed": 3}, build)
    [entry] = model_cache.glob("rock-*.npz")
    entry.unlink()
    again = cache.cached("rock", {"seed": 3}, build)
    assert build.calls == 1 and again.parts and entry.exists()


@pytest.mark.parametrize("text, limit", [("20G", 20 * 2 ** 30), ("512m", 512 * 2 ** 20), ("1.5T", int(1.5 * 2 ** 40)),
                                         ("3000000", 3_000_000), ("20GB", 20 * 2 ** 30), ("unlimited", None),
                                         ("", 20 * 2 ** 30)])
def test_the_cache_bound_reads_sizes_with_units(monkeypatch, text, limit):
    monkeypatch.setenv("MITSUFOREST_CACHE_SIZE", text)
    assert cache.cache_limit() == limit


@pytest.mark.parametrize("text", ["20X", "-5G", "lots", "100", "nanG", "infT", "B", "G"])
def test_a_bad_cache_bound_is_refused_before_a_render_in_one_line(tmp_path, monkeypatch, capsys, text):
    from mitsuforest.cli import main
    monkeypatch.setenv("MITSUFOREST_CACHE_SIZE", text)
    scene = tmp_path / "scene.yaml"
    scene.write_text("name: s\narea: {size: [10, 10]}\n")
    assert main(["render", str(scene), "-o", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == (f"mitsuforest: MITSUFOREST_CACHE_SIZE: must be a size of 1M or more (bytes, "
                                       f"or with K, M, G or T: 20G) or 'unlimited', got {text!r}\n")
    assert not (tmp_path / "out").exists()


def test_key_follows_the_generator_code(model_cache, monkeypatch):
    assert cache.code_hash() == cache.code_hash() and len(cache.code_hash()) == 20
    build = Builds()
    key = cache.cache_key("rock", {"seed": 3})
    cache.cached("rock", {"seed": 3}, build)
    monkeypatch.setattr(cache, "code_hash", lambda: "edited generators")
    assert cache.cache_key("rock", {"seed": 3}) != key
    cache.cached("rock", {"seed": 3}, build)
    assert build.calls == 2 and len(list(model_cache.glob("rock-*.npz"))) == 2


@pytest.mark.parametrize("edited, counts", [("skeleton.py", True), ("understory.py", True), ("classes.py", True),
                                             ("seeds.py", True),
                                             ("gallery.py", False), ("cache.py", False)])
def test_code_hash_changes_with_the_generators_source(monkeypatch, edited, counts):
    read = Path.read_bytes
    before = cache.code_hash()
    monkeypatch.setattr(Path, "read_bytes", lambda p: read(p) + (b"# edited" if p.name == edited else b""))
    cache.code_hash.cache_clear()
    try:
        assert (cache.code_hash() != before) == counts
    finally:
        cache.code_hash.cache_clear()


def test_code_hash_changes_with_a_library_version(monkeypatch):
    before = cache.code_hash()
    monkeypatch.setattr(cache.importlib.metadata, "version", lambda dist: "0.0")
    cache.code_hash.cache_clear()
    try:
        assert cache.code_hash() != before
    finally:
        cache.code_hash.cache_clear()


@pytest.mark.parametrize("dist", ["numpy", "trimesh", "manifold3d", "pymeshfix", "scipy"])
def test_code_hash_changes_with_each_library_that_shapes_a_model(monkeypatch, dist):
    """A new version of any one library whose results a model's bytes hold (pymeshfix repairs imported
    wood; scipy finds trimesh's loose parts) makes a new key, so no stale repair is reused."""
    version = cache.importlib.metadata.version
    before = cache.code_hash()
    monkeypatch.setattr(cache.importlib.metadata, "version", lambda d: "0.0" if d == dist else version(d))
    cache.code_hash.cache_clear()
    try:
        assert cache.code_hash() != before
    finally:
        cache.code_hash.cache_clear()


@pytest.mark.parametrize("damage", [b"", b"not a zip file", b"PK\x03\x04 truncated zip"])
def test_damaged_entry_is_rebuilt(model_cache, damage):
    build = Builds()
    good = cache.cached("rock", {"seed": 3}, build)
    [entry] = model_cache.glob("rock-*.npz")
    entry.write_bytes(damage)
    rebuilt = cache.cached("rock", {"seed": 3}, build)
    assert build.calls == 2 and np.array_equal(rebuilt.parts[0].faces, good.parts[0].faces)
    cache.cached("rock", {"seed": 3}, build)
    assert build.calls == 2  # the rebuilt entry replaced the damaged one


def test_unreadable_entry_is_rebuilt(model_cache, monkeypatch):
    build = Builds()
    cache.cached("rock", {"seed": 3}, build)

    def denied(*_):
        raise PermissionError(13, "Permission denied")
    monkeypatch.setattr(cache.np, "load", denied)
    cache._in_memory.clear()   # as another process would
    assert cache.cached("rock", {"seed": 3}, build).parts and build.calls == 2


def test_a_process_reads_an_entry_once_and_hands_out_copies(model_cache, monkeypatch):
    """A dataset worker renders plot after plot of the same models: after the first, they come from
    memory (np.load is not called again), each caller gets its own Model over read-only arrays, and an
    entry replaced on disk is read again."""
    build = Builds()
    first = cache.cached("rock", {"seed": 3}, build)
    loads = []
    real_load = cache.np.load
    monkeypatch.setattr(cache.np, "load", lambda *a, **k: loads.append(a) or real_load(*a, **k))
    second = cache.cached("rock", {"seed": 3}, build)
    assert loads == [] and build.calls == 1
    assert second is not first and second.parts is not first.parts
    assert second.parts[0].vertices is first.parts[0].vertices and not second.parts[0].vertices.flags.writeable
    second.name = "renamed"
    assert first.name != "renamed"
    np.testing.assert_array_equal(second.hull_corners(), first.hull_corners())
    [entry] = model_cache.glob("rock-*.npz")
    entry.write_bytes(entry.read_bytes())   # the same bytes, a new modification time
    os.utime(entry, ns=(1, 1))
    cache.cached("rock", {"seed": 3}, build)
    assert len(loads) == 1 and build.calls == 1


def test_a_stored_entry_holds_its_hull(model_cache):
    """The scene culls placed copies by their model's hull corners: stored with the entry, read back."""
    model = cache.cached("rock", {"seed": 3}, Builds())
    cache._in_memory.clear()
    [entry] = model_cache.glob("rock-*.npz")
    with np.load(entry) as data:
        stored = data["hull"]
    from scipy.spatial import ConvexHull
    v = model.vertices()
    np.testing.assert_array_equal(stored, v[ConvexHull(v).vertices])
    np.testing.assert_array_equal(cache.cached("rock", {"seed": 3}, Builds()).hull, stored)


NORMALS_COMPUTED = []


def _counted_normals(vertices, faces):
    """Face normals, counting the calls (a named function, as those whose results the cache keeps)."""
    from mitsuforest.scene.meshes import face_normals
    NORMALS_COMPUTED.append(len(faces))
    return face_normals(vertices, faces)


def test_what_a_cached_part_derives_is_kept_beside_it_and_read_back_the_same(model_cache):
    """A cached model's face normals, triangle areas and proxy cells (0.4 CPU s of a fresh demo render) are
    computed once: a later process reads them back bit for bit without computing them; a damaged file is
    computed again; neither a lambda's result nor a part that is not the cache's is stored."""
    NORMALS_COMPUTED.clear()
    part = cache.cached("rock", {"seed": 3}, Builds()).parts[0]
    first = part.of_mesh(_counted_normals)
    [kept] = (model_cache / "derived").glob("rock-*-part0-_counted_normals-*.npz")
    assert NORMALS_COMPUTED == [len(part.faces)] and not first.flags.writeable
    cache._in_memory.clear()                          # as another process would
    again = cache.cached("rock", {"seed": 3}, Builds()).parts[0].of_mesh(_counted_normals)
    assert len(NORMALS_COMPUTED) == 1 and again.dtype == first.dtype and np.array_equal(again, first)
    assert again is not first and not again.flags.writeable
    kept.write_bytes(b"PK\x03\x04 truncated zip")
    cache._in_memory.clear()
    assert np.array_equal(cache.cached("rock", {"seed": 3}, Builds()).parts[0].of_mesh(_counted_normals), first)
    assert len(NORMALS_COMPUTED) == 2
    cache.cached("rock", {"seed": 3}, Builds()).parts[0].of_mesh(lambda v, f: np.ones(len(f)))
    loose = rock_model(seed=3, name="rock").parts[0]
    loose.vertices.flags.writeable = loose.faces.flags.writeable = False
    loose.of_mesh(_counted_normals)
    assert len(list((model_cache / "derived").iterdir())) == 1 and len(NORMALS_COMPUTED) == 3

@pytest.fixture
def pids():
    """(pid of a running process, pid of a process that has ended)."""
    live = subprocess.Popen(["sleep", "60"])
    ended = subprocess.Popen(["true"])
    ended.wait()
    yield live.pid, ended.pid
    live.kill()
    live.wait()


def test_staging_removes_only_its_own_and_dead_renders_folders(tmp_path, pids):
    live, dead = pids
    running_here = tmp_path / f".test.partial-abc123-{HOST}-{live}"
    dead_here = tmp_path / f".test.partial-def456-{HOST}-{dead}"
    other_host = tmp_path / f".test.partial-ghi789-other.host-{dead}"
    unknown_owner = tmp_path / f".test.partial-{dead}"
    other_scene = tmp_path / f".other.partial-jkl012-{HOST}-{dead}"
    for p in (running_here, dead_here, other_host, unknown_owner, other_scene):
        p.mkdir()
        (p / "test.pcd").write_text("points of another render")

    staging = Staging(tmp_path, "test")
    assert not dead_here.exists()
    staging.file(".pcd").write_text("ours")
    staging.file("_manifest.json").write_text("{}")
    assert [p.name for p in staging.commit()] == ["test.pcd", "test_manifest.json"]
    Staging(tmp_path, "test").discard()

    hidden = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("."))
    assert hidden == sorted(p.name for p in (running_here, other_host, unknown_owner, other_scene))
    assert (running_here / "test.pcd").read_text() == "points of another render"
    assert (tmp_path / "test.pcd").read_text() == "ours"


@pytest.fixture
def disk_events(monkeypatch):
    """Every os.fsync and os.replace, in order: ("fsync", inode) and ("replace", inode of the source)."""
    events, fsync, replace = [], os.fsync, os.replace

    def record_fsync(fd):
        events.append(("fsync", os.fstat(fd).st_ino))
        fsync(fd)

    def record_replace(source, target):
        events.append(("replace", os.stat(source).st_ino))
        replace(source, target)
    monkeypatch.setattr(os, "fsync", record_fsync)
    monkeypatch.setattr(os, "replace", record_replace)
    return events


def test_atomic_write_flushes_the_file_before_its_rename_and_the_folder_after(tmp_path, disk_events):
    from mitsuforest.write.atomic import write_text
    write_text(tmp_path / "a.txt", "content")
    file, folder = (tmp_path / "a.txt").stat().st_ino, tmp_path.stat().st_ino
    assert disk_events == [("fsync", file), ("replace", file), ("fsync", folder)]


def test_staging_commit_flushes_each_file_before_its_rename_and_the_folder_after(tmp_path, disk_events):
    staging = Staging(tmp_path, "test")
    staging.file(".pcd").write_text("points")
    staging.file("_manifest.json").write_text("{}")
    staging.commit()
    pcd, manifest = (tmp_path / "test.pcd").stat().st_ino, (tmp_path / "test_manifest.json").stat().st_ino
    folder = tmp_path.stat().st_ino
    renames = [e for e in disk_events if e[0] == "replace"]
    assert renames == [("replace", pcd), ("replace", manifest)]            # the manifest last
    for ino in (pcd, manifest):
        assert disk_events.index(("fsync", ino)) < disk_events.index(("replace", ino))
    assert disk_events[-1] == ("fsync", folder)                              # every name in place on disk
    before_manifest = disk_events[:disk_events.index(("replace", manifest))]
    assert before_manifest[-1] == ("fsync", folder)                          # the others' names before it


def test_two_stagings_of_one_process_are_apart(tmp_path):
    a, b = Staging(tmp_path, "test"), Staging(tmp_path, "test")
    assert a.path != b.path and a.path.name.endswith(f"-{HOST}-{os.getpid()}")
    a.discard()
    assert b.path.is_dir()


def _points(n=5):
    points = np.zeros(n, POINT_DTYPE)
    points["x"], points["y"], points["z"] = 500000 + np.arange(n), 6000000.0, 1.0
    points["return_number"] = points["number_of_returns"] = 1
    return points


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_carries_a_standard_wkt_crs(tmp_path, suffix):
    path = tmp_path / ("t" + suffix)
    write_las(path, _points(), [500000.0, 6000000.0, 0.0], crs="EPSG:7855")
    header = laspy.read(str(path)).header
    assert header.global_encoding.wkt
    assert header.parse_crs().to_epsg() == 7855
    assert header.parse_crs().name == "GDA2020 / MGA zone 55"


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_more_than_15_returns_are_written_as_15(tmp_path, suffix):
    """Point format 6 has 4 bits per return field: a pulse of 20 echoes (61 sub-rays, max_returns 0)
    is written with its return numbers and count capped at 15 instead of failing mid-render."""
    points = _points(20)
    points["return_number"], points["number_of_returns"] = np.arange(1, 21), 20
    write_las(tmp_path / ("t" + suffix), points, [500000.0, 6000000.0, 0.0])
    las = laspy.read(str(tmp_path / ("t" + suffix)))
    assert np.asarray(las.return_number).tolist() == list(range(1, 16)) + [15] * 5
    assert set(np.asarray(las.number_of_returns).tolist()) == {15}
    assert np.allclose(las.x, points["x"])


OFFSET = [500000.0, 6000000.0, 0.0]


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_creation_date_is_never_the_day_of_the_run(tmp_path, monkeypatch, suffix):
    """The header's creation date is 2000-01-01, or the day of SOURCE_DATE_EPOCH: a file written on
    another day has the same bytes (a dataset rendered across midnight gave other LAZ bytes)."""
    import datetime

    import laspy.header

    class OtherDay(datetime.date):
        @classmethod
        def today(cls):
            return cls(2031, 7, 9)
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    write_las(tmp_path / ("today" + suffix), _points(), OFFSET)
    monkeypatch.setattr(laspy.header, "date", OtherDay)
    write_las(tmp_path / ("other_day" + suffix), _points(), OFFSET)
    assert (tmp_path / ("today" + suffix)).read_bytes() == (tmp_path / ("other_day" + suffix)).read_bytes()
    assert laspy.read(str(tmp_path / ("today" + suffix))).header.creation_date == datetime.date(2000, 1, 1)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")   # 2023-11-14 22:13:20 UTC
    write_las(tmp_path / ("epoch" + suffix), _points(), OFFSET)
    assert laspy.read(str(tmp_path / ("epoch" + suffix))).header.creation_date == datetime.date(2023, 11, 14)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "yesterday")
    with pytest.raises(UserError, match="SOURCE_DATE_EPOCH: must be whole seconds since 1970-01-01 UTC, got 'yesterday'"):
        write_las(tmp_path / ("bad" + suffix), _points(), OFFSET)
    assert not (tmp_path / ("bad" + suffix)).exists()


def test_las_without_crs_has_no_crs_vlr_but_the_wkt_bit(tmp_path):
    write_las(tmp_path / "t.las", _points(), [500000.0, 6000000.0, 0.0])
    header = laspy.read(str(tmp_path / "t.las")).header
    assert header.parse_crs() is None
    assert header.global_encoding.wkt  # LAS 1.4 demands it for point format 6; PDAL refuses files without


@pytest.mark.parametrize("text, reason", [("EPSG:999999", "crs not found"), ("UTM 55 south", "unknown name")])
def test_invalid_crs_is_a_user_error(tmp_path, text, reason):
    with pytest.raises(UserError, match=rf"^origin\.crs: '{text}' is not a coordinate reference system \(.*{reason}"):
        crs_wkt(text)
    with pytest.raises(UserError, match="origin.crs"):
        write_las(tmp_path / "t.las", _points(), [0.0, 0.0, 0.0], crs=text)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("text, problem", [("EPSG:4326", "is geographic, in degrees"),
                                           ("EPSG:4978", "is not a projected CRS"),
                                           ("EPSG:2263", "has its axes in US survey foot")])
def test_crs_not_in_projected_metres_is_refused(text, problem):
    """Offsets in metres added to degrees (or feet) would put every point in the wrong place."""
    with pytest.raises(UserError, match=rf"^origin\.crs: '{text}' \(.*\) {problem}; .*metres"):
        crs_wkt(text)


def test_compound_crs_with_a_metric_projection_is_accepted():
    assert crs_wkt("EPSG:7855+5711").startswith('COMPD_CS["GDA2020 / MGA zone 55 + AHD height"')


def test_crs_wkt_is_wkt1_with_the_epsg_authority():
    wkt = crs_wkt("EPSG:7855")
    assert wkt.startswith('PROJCS["GDA2020 / MGA zone 55"') and wkt.endswith('AUTHORITY["EPSG","7855"]]')


def test_for_instance_profile_header_dates_as_ours(monkeypatch):
    """The FOR-instance profile's LAS header takes its creation date as ours (2000-01-01 or
    SOURCE_DATE_EPOCH's day), not the day of the run."""
    import datetime

    from mitsuforest.write.output_profiles import for_instance_header
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    assert for_instance_header(OFFSET, None).creation_date == datetime.date(2000, 1, 1)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    assert for_instance_header(OFFSET, None).creation_date == datetime.date(2023, 11, 14)


def test_an_archetypes_crown_is_kept_in_the_cache_and_read_back_the_same(model_cache, monkeypatch):
    """The plan's crown of an archetype (its skeleton grown, 0.05-0.1 CPU s) is stored once and read back
    by a later process bit for bit, without growing the skeleton again; a drawn unique tree's is not
    stored (its model is not either)."""
    import mitsuforest.trees as trees
    from mitsuforest.specs.archetypes import DEFAULT_ARCHETYPES
    a, drawn = DEFAULT_ARCHETYPES[0], DEFAULT_ARCHETYPES[1]
    trees._archetype_shape.cache_clear()
    grown, components = trees.tree_shape(a)
    [entry] = model_cache.glob("crown-*.npz")
    trees.tree_shape(drawn, keep=False)
    assert len(list(model_cache.glob("crown-*.npz"))) == 1
    trees._archetype_shape.cache_clear()               # as another process would
    with monkeypatch.context() as m:
        m.setattr(trees, "grow", lambda _: pytest.fail("the skeleton was grown again"))
        crown, again = trees.tree_shape(a)
    assert np.array_equal(crown, grown) and crown.dtype == np.float64 and again == components > 10
    assert not crown.flags.writeable
    entry.write_bytes(b"PK\x03\x04 truncated zip")       # a damaged entry is grown again
    trees._archetype_shape.cache_clear()
    assert np.array_equal(trees.tree_shape(a)[0], grown)
    trees._archetype_shape.cache_clear()


def test_workers_setting_up_one_plot_build_in_their_own_orders_and_read_what_the_others_built(model_cache,
                                                                                              monkeypatch):
    """Leg tasks of one plot on several workers each build its models: the second, in an order of its
    own, builds them all; the first, in the plan's order, then reads every one the second stored instead
    of building it. Both get every model, in the plan's order, the same arrays."""
    from types import SimpleNamespace

    import mitsuforest.trees as trees
    from mitsuforest.plan import ModelSpec
    from mitsuforest.specs.understory import UNDERSTORY_COMPONENTS
    names = [f"rock{i:03d}" for i in range(1, 7)]
    plan = SimpleNamespace(models={n: ModelSpec("rock", UNDERSTORY_COMPONENTS, seed=i) for i, n in enumerate(names)})
    built = []
    monkeypatch.setitem(trees._BUILDERS, "rock", lambda name, **params: built.append(params["seed"]) or
                        trees.rock_model(name=name, **params))
    order = []
    second = trees.build_models(plan, progress=order.append, order=[3, 5, 0, 4, 1, 2])
    assert order == [names[i] for i in (3, 5, 0, 4, 1, 2)] and built == [3, 5, 0, 4, 1, 2] and list(second) == names
    cache._in_memory.clear()                          # the first worker, another process
    first = trees.build_models(plan)
    assert len(built) == 6 and list(first) == names
    for name in names:
        assert np.array_equal(first[name].parts[0].vertices, second[name].parts[0].vertices)


def test_a_process_forked_from_one_that_rendered_refuses_to_render():
    """A render in a child forked after its parent had rendered waited for ever on the parent's Dr.Jit and lazrs
    threads, which a fork does not copy (the demo scene, in a ``fork`` pool): it is refused, naming ``spawn``.
    The process that rendered renders on."""
    from mitsuforest import threads
    from mitsuforest.config import load_scene
    from mitsuforest.survey import prepare
    threads.note_native_threads()                     # as loading a scene into Mitsuba does
    threads.refuse_forked_render()                    # this process renders on
    read, write = os.pipe()
    child = os.fork()
    if child == 0:                                    # pragma: no cover (the child reports through the pipe)
        try:
            prepare(load_scene("scenes/demo.yaml"))
            os.write(write, b"rendered")
        except UserError as e:
            os.write(write, str(e).encode()[:4000])
        finally:
            os._exit(0)
    os.close(write)
    import select
    if not select.select([read], [], [], 120)[0]:     # the child hangs in the render it should have refused
        os.kill(child, 9)
    said = os.read(read, 4096).decode() if select.select([read], [], [], 0)[0] else "no answer in 120 s"
    os.waitpid(child, 0)
    assert said.startswith("this process was forked from one that had rendered") and "'spawn'" in said, said
