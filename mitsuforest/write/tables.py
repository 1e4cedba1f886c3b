"""CSV tables: wood volumes, ids of every object and component, and the platform trajectory."""

from __future__ import annotations

import csv
import io

import numpy as np

from ..classes import GROUND, TREE_LEAVES, TREE_WOOD
from .atomic import write_text


def csv_text(header, rows) -> str:
    """CSV text with a header row and ``\n`` line ends."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def _f(x, digits=9):
    return "" if np.isnan(x) else f"{x:.{digits}g}"


def _source(model) -> str:
    """The file an imported tree came from (forest.models); empty for generated models."""
    return model.meta.get("source", "")


WOODY_KINDS = ("tree", "deadwood", "stump")   # the kinds whose wood volume is tabled


def volume_rows(plan, models: dict, offset) -> list[list]:
    """One row per tree archetype, deadwood piece and stump model, then one per placed tree, deadwood
    piece and stump."""
    rows = []
    for name, spec in plan.models.items():
        if spec.kind in WOODY_KINDS and name in models and models[name].volume:
            v = models[name].volume
            rows.append([spec.kind + "_model", name, "", _f(v.union), _f(v.analytic), _f(v.naive), v.parts,
                         "", "", "", "", spec.species, _source(models[name]), v.repaired, v.skipped])
    for obj in plan.objects:
        if obj.kind in WOODY_KINDS and models[obj.model].volume:
            v = models[obj.model].volume
            x, y, z = (p + o for p, o in zip(obj.position, offset))
            rows.append([obj.kind, obj.model, obj.instance, _f(v.union), _f(v.analytic), _f(v.naive),
                         v.parts, obj.treeid, f"{x:.4f}", f"{y:.4f}", f"{z:.4f}",
                         plan.models[obj.model].species, _source(models[obj.model]), v.repaired, v.skipped])
    return rows


def write_volumes(path, plan, models, offset) -> None:
    """Volumes (see :func:`volume_rows`). ``parts_repaired`` and ``parts_skipped`` count the wood parts of
    an imported mesh that the repair changed or left out of the volume (``repair: skip``)."""
    header = ["row", "model", "instance", "volume_union_m3", "volume_analytic_m3", "volume_naive_m3",
              "parts", "treeid", "x", "y", "z", "species", "source", "parts_repaired", "parts_skipped"]
    write_text(path, csv_text(header, volume_rows(plan, models, offset)))


def component_treeid(obj, comp) -> int:
    """The treeid of one component of a placed object: the object's for tree wood and leaves and for
    deadwood, else 0 (a tree's other components, rocks, bushes ...)."""
    return obj.treeid if comp.classification in (TREE_WOOD, TREE_LEAVES) or obj.kind == "deadwood" else 0


def write_ids(path, plan, models, offset) -> None:
    """Every object and component: object_id, instance, treeid, classification, kind, model, position,
    species (the name; its code is the points' ``species`` field, classes.SPECIES_CODES), source (the file
    of an imported tree)."""
    rows = [[plan.ground_object_id, 0, 0, GROUND, "ground", "", "", "", "", "none", ""]]
    for obj in plan.objects:
        x, y, z = (f"{p + o:.4f}" for p, o in zip(obj.position, offset))
        species = plan.models[obj.model].species
        for k, comp in enumerate(models[obj.model].components):
            rows.append([obj.object_id + k, obj.instance, component_treeid(obj, comp), comp.classification, comp.kind,
                         obj.model, x, y, z, species, _source(models[obj.model])])
    write_text(path, csv_text(["object_id", "instance", "treeid", "classification", "kind", "model", "x", "y", "z",
                               "species", "source"], rows))


TRAJECTORY_RATE = 10.0   # Hz


def leg_times(t0: float, t1: float, rate: float = TRAJECTORY_RATE) -> np.ndarray:
    """The times of a leg's trajectory rows: every ``1 / rate`` s from its start ``t0``, and its end ``t1``
    (its last pulse is fired just before it), so that a file of them flies the leg again whole."""
    t = np.arange(t0, t1, 1 / rate)
    return np.append(t[t < t1 - 1e-9], t1)


def trajectory(legs, platform, navigation=None, rate: float = TRAJECTORY_RATE) -> np.ndarray:
    """The platform's trajectory as flown, ``rate`` rows a second on each leg and one at its end
    (:func:`leg_times`): (n, 8) time, x, y, z,
    roll, pitch, yaw (deg, yaw clockwise from north; plan/trajectory.py has the frames) and the leg's
    number from 1 (the points' ``point_source_id``); with a
    :class:`~mitsuforest.scan.navigation.NavigationModel`, six more columns: the believed x, y, z, roll,
    pitch, yaw the points were computed with.

    :param platform: the scene's :class:`~mitsuforest.scan.platform.Platform`.
    """
    from ..plan.trajectory import ENU_FROM_NED, matrix_euler
    rows = []
    for number, leg in enumerate(legs, start=1):
        t = leg_times(leg.t0, leg.t1, rate)
        table = platform.table(leg)
        position, body = platform.body_pose(leg, table, t)
        columns = [t, position, matrix_euler(ENU_FROM_NED.T @ body), np.full(len(t), number)]
        if navigation is not None:
            columns.append(navigation.trajectory(leg, table, t))
        rows.append(np.column_stack(columns))
    return np.vstack(rows) if rows else np.zeros((0, 8 if navigation is None else 14))


def write_trajectory(path, scene, plan) -> None:
    """``NAME_trajectory.csv``: :func:`trajectory` with ``origin.offset`` added to x, y, z. Its first seven
    columns are a trajectory file that ``survey.trajectory`` flies again (the ``line`` column keeps the legs)."""
    from ..scan import Platform, navigation_model
    platform = Platform(scene)
    navigation = navigation_model(scene, plan, platform)
    tr = trajectory(plan.legs, platform, navigation)
    offset = np.asarray(scene.origin.offset, float)
    tr[:, 1:4] += offset
    header = "time,x,y,z,roll,pitch,yaw,line"
    row = "{:.6f},{:.4f},{:.4f},{:.4f},{:.4f},{:.4f},{:.4f},{:.0f}"
    if navigation is not None:
        tr[:, 8:11] += offset
        header += ",believed_x,believed_y,believed_z,believed_roll,believed_pitch,believed_yaw"
        row += ",{:.4f},{:.4f},{:.4f},{:.4f},{:.4f},{:.4f}"
    write_text(path, header + "\n" + "".join(row.format(*r) + "\n" for r in tr))
