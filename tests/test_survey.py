"""``prepare``, ``scan`` and ``write``: a survey prepared for some legs loads only the objects in their
reach and scans them into the same bytes as the whole survey's scene; batches scanned apart and
written by a survey prepared for no legs are the render's points; on a GPU the device's part of the scan runs ahead."""

import itertools
import threading

import numpy as np
import pytest

from conftest import ROOT
from helpers import settled
from mitsuforest.config import load_scene
from mitsuforest.pipeline import render
from mitsuforest.scan import POINT_DTYPE, READ_AHEAD, READ_AHEAD_VARIABLE, PulseTracer, ScanResult, read_ahead
from mitsuforest.survey import Batches, prepare, scan, write


@pytest.fixture(scope="module")
def narrow(tmp_path_factory, variant):
    """The demo's three legs (12 m apart) with a 30° field of view, so each leg reaches about 8 m to its
    sides at ground level and the first leg's side of the plot is out of reach of the other two."""
    scene = load_scene(ROOT / "scenes" / "demo.yaml", variant=variant, output_dir=tmp_path_factory.mktemp("narrow"))
    return scene.with_({"sensor.field_of_view": 30.0, "survey.pulse_frequency": 100000, "survey.speed": 6.0,
                        "simulation.beam_samples": 1, "simulation.beam_pattern": "fixed"})


@pytest.fixture(scope="module")
def whole(narrow):
    return prepare(narrow)


def _points(batches: Batches) -> np.ndarray:
    return np.concatenate(list(batches))


@pytest.mark.parametrize("legs", [range(0, 1), range(1, 3)], ids=["leg 1", "legs 2-3"])
def test_a_survey_prepared_for_some_legs_scans_the_same_bytes_as_the_whole(narrow, whole, legs):
    part = prepare(narrow, legs=legs)
    assert len(whole.plan.legs) == 3 and whole.scan_scene.culled == 0
    assert whole.scan_scene.loaded == whole.scan_scene.objects == len(whole.plan.objects) == 20
    # the first leg reaches 8 of the 20 objects (trees of the plot's west side); the other two reach all
    assert part.scan_scene.loaded == {range(0, 1): 9, range(1, 3): 20}[legs]
    # the counts, box and triangles stay the whole survey's, so the same pulses are cast
    assert (part.scan_scene.objects, part.scan_scene.culled, part.scan_scene.triangles) == \
        (whole.scan_scene.objects, whole.scan_scene.culled, whole.scan_scene.triangles)
    np.testing.assert_array_equal(part.scan_scene.bbox, whole.scan_scene.bbox)
    apart, together = scan(part), scan(whole, legs=legs)
    a, b = _points(apart), _points(together)
    assert len(a) > 10_000 and set(np.unique(a["point_source_id"])) == {k + 1 for k in legs}
    assert a.tobytes() == b.tobytes()
    assert (apart.result.pulses_cast, apart.result.rays) == (together.result.pulses_cast, together.result.rays)
    # every object the legs' points hit in the whole survey's scene was loaded
    loaded = set(part.scan_scene.table.object_instance.tolist())
    assert set(np.unique(b["instance"][b["instance"] > 0]).tolist()) <= loaded


def test_a_survey_scans_only_the_legs_it_was_prepared_for(narrow):
    first = prepare(narrow, legs=range(0, 1))
    with pytest.raises(ValueError, match="were not prepared"):
        scan(first, legs=range(0, 2))
    with pytest.raises(ValueError, match="not consecutive legs"):
        prepare(narrow, legs=range(2, 4))


def test_batches_scanned_leg_by_leg_and_written_together_are_the_render(narrow, whole):
    """What a dataset's merge does: batches scanned by surveys prepared for one leg each, written by a
    survey prepared for none (the ground alone loaded)."""
    rendered = render(whole, write=False, progress=False, log=lambda *_: None)
    legs = [scan(prepare(narrow, legs=range(k, k + 1))) for k in range(3)]
    counts = ScanResult(pulses_emitted=sum(b.result.pulses_emitted for b in legs))
    writer = prepare(narrow, legs=range(0))
    assert writer.scan_scene.loaded == 0 and writer.scan_scene.objects == whole.scan_scene.objects
    written = write(writer, Batches(itertools.chain.from_iterable(legs), counts), None, keep_points=True)
    assert len(rendered.points) > 30_000
    assert written.points.tobytes() == rendered.points.tobytes()
    assert written.manifest["scene_objects"] == rendered.manifest["scene_objects"]
    assert written.manifest["classes"] == rendered.manifest["classes"]


def _threads_tracing(monkeypatch) -> list[int]:
    """A list that gets the thread of each batch's device part (``PulseTracer.echo_slots``) as it runs."""
    traced = []
    echo_slots = PulseTracer.echo_slots

    def counted(self, *args):
        traced.append(threading.get_ident())
        return echo_slots(self, *args)
    monkeypatch.setattr(PulseTracer, "echo_slots", counted)
    return traced


@pytest.mark.parametrize("ahead", [0, 2])
def test_the_device_traces_ahead_as_set_and_stops_when_the_batches_are_left(narrow, monkeypatch, ahead):
    """With ``READ_AHEAD`` batches (a GPU's 2; a CPU's 0, where the device is the host's own cores) the
    scan's device part traces the next batches on a thread of its own while the caller takes this one,
    into the same bytes; a caller that stops early (an error, an interrupt) stops it."""
    monkeypatch.setitem(READ_AHEAD, "llvm", ahead)
    monkeypatch.setitem(READ_AHEAD, "cuda", ahead)
    small = prepare(narrow.with_({"simulation.pulses_per_batch": 20_000}), legs=range(0, 1))
    echo_slots = PulseTracer.echo_slots
    traced = _threads_tracing(monkeypatch)
    batches = iter(scan(small))
    assert next(batches).dtype == POINT_DTYPE
    assert len(settled(traced, 1 + ahead)) == 1 + ahead       # the batch taken, and those ahead
    assert (threading.get_ident() in traced) == (ahead == 0)
    batches.close()
    assert len(settled(traced, 2 + ahead, timeout=0)) == 1 + ahead
    monkeypatch.setattr(PulseTracer, "echo_slots", echo_slots)
    points = _points(scan(small))
    monkeypatch.setitem(READ_AHEAD, "llvm", 2 - ahead)
    monkeypatch.setitem(READ_AHEAD, "cuda", 2 - ahead)
    assert len(points) > 10_000 and _points(scan(small)).tobytes() == points.tobytes()


def test_the_read_ahead_by_backend_or_the_variable(monkeypatch):
    from mitsuforest.errors import UserError
    monkeypatch.delenv(READ_AHEAD_VARIABLE, raising=False)
    assert read_ahead("llvm") == 0 and read_ahead("cuda") == 2
    monkeypatch.setenv(READ_AHEAD_VARIABLE, "0")
    assert read_ahead("cuda") == 0
    monkeypatch.setenv(READ_AHEAD_VARIABLE, " 3 ")
    assert read_ahead("llvm") == 3 and read_ahead("cuda") == 3
    for bad in ("two", "-1", "1.5"):
        monkeypatch.setenv(READ_AHEAD_VARIABLE, bad)
        with pytest.raises(UserError, match=f"{READ_AHEAD_VARIABLE}: must be a whole number >= 0, got '{bad}'"):
            read_ahead("cuda")


@pytest.mark.parametrize("default, variable", [(0, "1"), (2, "0")])
def test_the_variable_sets_the_read_ahead_of_a_render(narrow, monkeypatch, default, variable):
    """``MITSUFOREST_READ_AHEAD`` starts the read-ahead where the backend's default has none (a CPU's)
    and stops it where the default has some (a GPU's): the same bytes either way."""
    monkeypatch.setitem(READ_AHEAD, "llvm", default)
    monkeypatch.setitem(READ_AHEAD, "cuda", default)
    small = prepare(narrow.with_({"simulation.pulses_per_batch": 20_000}), legs=range(0, 1))
    traced = _threads_tracing(monkeypatch)
    monkeypatch.delenv(READ_AHEAD_VARIABLE, raising=False)
    points = _points(scan(small))
    assert len(traced) > 2 and (threading.get_ident() in traced) == (default == 0)
    traced.clear()
    monkeypatch.setenv(READ_AHEAD_VARIABLE, variable)
    assert _points(scan(small)).tobytes() == points.tobytes()
    assert len(traced) > 2 and (threading.get_ident() in traced) == (variable == "0")


def test_versions_are_read_once_and_each_caller_gets_its_own_copy(monkeypatch):
    """A dataset worker writes the library versions into every plot's manifest: they are read from the
    installed packages once per process, and a manifest that changes its copy changes no other."""
    import importlib.metadata

    from mitsuforest import survey
    first = survey.versions()
    assert first["numpy"] == importlib.metadata.version("numpy") and first["python"]
    monkeypatch.setattr(importlib.metadata, "version", lambda dist: 1 / 0)    # not read again
    first["numpy"] = "changed"
    assert survey.versions()["numpy"] == importlib.metadata.distribution("numpy").version
