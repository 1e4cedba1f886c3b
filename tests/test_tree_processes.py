"""Models and crowns built in worker processes (``trees/parallel.py``): the same bytes as one process builds,
each job in a worker, a worker's failure left to the caller."""

import dataclasses
import operator
import os

import numpy as np
import pytest

from mitsuforest import trees
from mitsuforest.cli import main
from mitsuforest.config import scene_from_mapping
from mitsuforest.errors import UserError
from mitsuforest.plan import plan_json
from mitsuforest.survey import make_plan
from mitsuforest.trees import parallel
from mitsuforest.trees.parallel import MIN_JOBS, PROCESSES_VARIABLE, build_processes, in_workers
from mitsuforest.write.processes import PROCESSES_VARIABLE as WRITER_PROCESSES, writer_processes


def test_each_job_runs_in_a_worker_and_comes_back_in_order():
    jobs = [(i, 4) for i in range(MIN_JOBS + 3)]
    assert list(in_workers(operator.truediv, jobs, processes=2)) == [(True, i / 4) for i in range(MIN_JOBS + 3)]
    pids = [pid for ok, pid in in_workers(os.getpid, [()] * MIN_JOBS, processes=2)]
    assert None not in pids and os.getpid() not in pids


def test_a_job_that_fails_in_its_worker_is_left_to_the_caller():
    jobs = [(1, 1)] * 3 + [(1, 0)] + [(2, 1)] * (MIN_JOBS - 4)
    assert list(in_workers(operator.truediv, jobs, processes=2)) == \
        [(True, 1.0)] * 3 + [(False, None)] + [(True, 2.0)] * (MIN_JOBS - 4)


def test_few_jobs_or_one_process_are_left_to_the_caller():
    assert list(in_workers(os.getpid, [()] * (MIN_JOBS - 1), processes=2)) == [(False, None)] * (MIN_JOBS - 1)
    assert list(in_workers(os.getpid, [()] * MIN_JOBS, processes=1)) == [(False, None)] * MIN_JOBS


def test_a_job_runs_under_the_callers_variables_of_now(monkeypatch):
    """The pool outlives a change of ``MITSUFOREST_CACHE`` (an API user's, a test's): a worker's job sees the
    caller's variables when it was submitted, those removed since among them."""
    list(in_workers(os.getpid, [()] * MIN_JOBS, processes=2))          # the pool started before the change
    monkeypatch.setenv("MITSUFOREST_CACHE", "/the/new/cache")
    monkeypatch.setenv("MITSUFOREST_TEST_SETTING", "set")
    seen = list(in_workers(os.getenv, [("MITSUFOREST_CACHE",)] * MIN_JOBS, processes=2))
    assert seen == [(True, "/the/new/cache")] * MIN_JOBS
    monkeypatch.delenv("MITSUFOREST_TEST_SETTING")
    seen = list(in_workers(os.getenv, [("MITSUFOREST_TEST_SETTING",)] * MIN_JOBS, processes=2))
    assert seen == [(True, None)] * MIN_JOBS


def test_the_processes_from_the_variable_or_the_cores(monkeypatch):
    monkeypatch.delenv(PROCESSES_VARIABLE, raising=False)
    monkeypatch.delenv(WRITER_PROCESSES, raising=False)
    assert build_processes(cores=6) == 6
    assert build_processes(cores=16) == 15 == writer_processes(cores=16)     # the writer's pool, shared
    assert build_processes(cores=1) == 0
    monkeypatch.setenv(PROCESSES_VARIABLE, "1")
    assert build_processes(cores=6) == 0
    monkeypatch.setenv(PROCESSES_VARIABLE, "3")
    assert build_processes(cores=6) == 3
    monkeypatch.setattr(parallel, "may_start_processes", lambda: False)     # a daemonic process
    assert build_processes(cores=6) == 0
    for bad in ("-1", "two", "1.5"):
        monkeypatch.setenv(PROCESSES_VARIABLE, bad)
        with pytest.raises(UserError, match=f"{PROCESSES_VARIABLE}: must be a whole number >= 0, got '{bad}'"):
            build_processes()


def test_a_bad_variable_is_refused_before_any_work(monkeypatch, capsys, tmp_path):
    monkeypatch.setenv(PROCESSES_VARIABLE, "many")
    assert main(["plan", "scenes/demo.yaml", "-o", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip() == \
        f"mitsuforest: {PROCESSES_VARIABLE}: must be a whole number >= 0, got 'many'"
    assert not (tmp_path / "out").exists()


def _listed_scene(tmp_path, rows: int):
    rng = np.random.default_rng(11)
    lines = ["x,y,height,crown_radius"] + [f"{x:.2f},{y:.2f},{h:.1f},{r:.2f}" for x, y, h, r in
                                           zip(rng.uniform(2, 28, rows), rng.uniform(2, 28, rows),
                                               rng.uniform(4, 9, rows), rng.uniform(0.8, 1.6, rows))]
    (tmp_path / "trees.csv").write_text("\n".join(lines) + "\n")
    return scene_from_mapping({
        "name": "listed", "seed": 4, "area": {"size": [30, 30]}, "terrain": {"type": "flat"},
        "forest": {"trees_file": str(tmp_path / "trees.csv")},
        "understory": {"bushes": 4, "rocks": 2, "deadwood": 2, "stumps": 1},
        "sensor": "sensors/riegl_vux-1uav22.yaml",
        "survey": {"altitude": 30, "speed": 4, "pulse_frequency": 100000, "scan_frequency": 50, "line_spacing": 15},
        "output": {"dir": str(tmp_path / "out")}})


def _plan_and_models(monkeypatch, tmp_path, scene, processes: int):
    """The plan and models of ``scene`` from an empty cache, with ``processes`` workers, and how each build
    the workers were asked for went (True: a worker made it)."""
    monkeypatch.setenv("MITSUFOREST_CACHE", str(tmp_path / f"cache{processes}"))
    monkeypatch.setenv(PROCESSES_VARIABLE, str(processes))
    made = []

    def spy(function, jobs, processes=None):
        for ok, value in in_workers(function, jobs, processes):
            made.append(ok)
            yield ok, value

    monkeypatch.setattr(trees, "in_workers", spy)
    plan = make_plan(scene)
    return plan, trees.build_models(plan), made


def test_a_tree_list_planned_and_built_in_workers_is_what_one_process_makes(monkeypatch, tmp_path):
    """Twelve listed trees and the understory, from empty caches: the plan and every model's vertices, faces,
    components and wood volume equal to the bit, and the workers made every crown and model."""
    scene = _listed_scene(tmp_path, 12)
    alone, alone_models, made = _plan_and_models(monkeypatch, tmp_path, scene, 0)
    builds = 12 + len(alone_models)                # 12 crowns, then 12 trees and the understory's models
    assert len(alone_models) > 12 + MIN_JOBS
    assert made == [False] * builds                # no workers: the caller built them all
    apart, apart_models, made = _plan_and_models(monkeypatch, tmp_path, scene, 2)
    assert made == [True] * builds
    assert plan_json(apart) == plan_json(alone)
    assert list(apart_models) == list(alone_models)
    for name, model in alone_models.items():
        other = apart_models[name]
        assert model.volume == other.volume, name
        assert len(model.parts) == len(other.parts)
        for a, b in zip(model.parts, other.parts):
            assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces), name
            assert np.array_equal(a.component, b.component), name
        assert not any(p.vertices.flags.writeable for p in other.parts)    # read from the cache, as one process's


def test_a_plots_unique_trees_come_back_from_the_workers_whole(monkeypatch, tmp_path):
    """Drawn trees are not cached (one plot's own): a worker hands its model back whole."""
    scene = scene_from_mapping({
        "name": "unique", "seed": 9, "area": {"size": [30, 30]}, "terrain": {"type": "flat"},
        "forest": {"trees": 10, "archetypes": [{"species": "acacia", "unique": MIN_JOBS}]},
        "understory": {"bushes": 0, "rocks": 0, "deadwood": 0, "stumps": 0},
        "sensor": "sensors/riegl_vux-1uav22.yaml",
        "survey": {"altitude": 30, "speed": 4, "pulse_frequency": 100000, "scan_frequency": 50, "line_spacing": 15},
        "output": {"dir": str(tmp_path / "out")}})
    alone, alone_models, _ = _plan_and_models(monkeypatch, tmp_path, scene, 0)
    apart, apart_models, made = _plan_and_models(monkeypatch, tmp_path, scene, 2)
    assert made == [True] * 2 * MIN_JOBS and len(apart_models) == MIN_JOBS
    assert plan_json(apart) == plan_json(alone)
    for name, model in alone_models.items():
        assert apart_models[name].volume == model.volume
        assert all(np.array_equal(a.vertices, b.vertices) for a, b in zip(model.parts, apart_models[name].parts))
    assert not list((tmp_path / "cache2").rglob("tree-*.npz"))       # nor stored by the workers


def test_a_dataset_worker_builds_in_one_process(monkeypatch):
    """A dataset's workers share the cores already (as their point writers do)."""
    from mitsuforest.dataset.tasks import set_threads
    monkeypatch.setenv(PROCESSES_VARIABLE, "1")     # so that the test's end removes what set_threads sets
    monkeypatch.delenv(PROCESSES_VARIABLE)
    set_threads(None)
    assert build_processes(cores=16) == 0


def test_the_crowns_progress_once_each(monkeypatch, tmp_path):
    """``tree_shapes(..., progress=f)`` calls ``f`` once a crown is had, each of them, from the workers too
    (what the plan's bar counts)."""
    monkeypatch.setenv("MITSUFOREST_CACHE", str(tmp_path / "cache"))
    template = trees.DEFAULT_ARCHETYPES[0]
    sources = [dataclasses.replace(template, seed=template.seed + i) for i in range(MIN_JOBS + 1)]
    calls = []
    for processes in ("0", "2"):
        monkeypatch.setenv(PROCESSES_VARIABLE, processes)
        shapes = trees.tree_shapes(sources, keep=False, progress=lambda: calls.append(processes))
        assert len(shapes) == len(sources)
    assert calls == ["0"] * len(sources) + ["2"] * len(sources)
