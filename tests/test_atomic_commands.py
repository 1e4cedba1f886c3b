"""`mitsuforest trees` and `mitsuforest export` write all their files or none: interrupted, or failing on
a full disk (named in one line, exit 1), they leave the output folder as it was."""

import errno
import os
from pathlib import Path

import pytest

from helpers import tiny_scene

SCENE = tiny_scene(1, 0, 0, 0, 0, thin_beam=False)
ENOSPC = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))    # as a failing write raises it: no file named


def _failing_on_call(n: int, error, real):
    """``real``, raising ``error`` on its n-th call."""
    calls = []

    def method(*args, **kwargs):
        calls.append(1)
        if len(calls) == n:
            raise error
        return real(*args, **kwargs)
    return method


def _earlier_files(folder: Path, names) -> dict:
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        (folder / name).parent.mkdir(exist_ok=True)
        (folder / name).write_bytes(b"earlier")
    return _snapshot(folder)


def _snapshot(folder: Path) -> dict:
    """Every entry under ``folder``, hidden ones included, with the content of files."""
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else None for p in sorted(folder.rglob("*"))}


@pytest.fixture
def one_archetype(monkeypatch):
    """`mitsuforest trees` of one archetype instead of the built-in ten."""
    from mitsuforest.specs import archetypes
    monkeypatch.setattr(archetypes, "DEFAULT_ARCHETYPES", archetypes.DEFAULT_ARCHETYPES[:1])


@pytest.mark.parametrize("error, code, message", [
    (KeyboardInterrupt(), 130, "mitsuforest: interrupted; no finished output was written (partial files removed). "
                               "Run the same command again to redo it."),
    (ENOSPC, 1, "mitsuforest: {out}/tree01_leaves.ply: No space left on device; nothing was finished (partial "
                "files removed)"),
])
def test_trees_interrupted_or_on_a_full_disk_leaves_the_folder_as_it_was(tmp_path, capsys, monkeypatch,
                                                                        one_archetype, error, code, message):
    """The second PLY fails: the earlier gallery is untouched, no new PLY and no staging folder stays."""
    import trimesh
    from mitsuforest.cli import main
    out = tmp_path / "gallery"
    before = _earlier_files(out, ["tree01_wood.ply", "volumes.csv", "notes.txt"])
    monkeypatch.setattr(trimesh.Trimesh, "export", _failing_on_call(2, error, trimesh.Trimesh.export))
    assert main(["trees", "-o", str(out)]) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == message.format(out=out)
    assert _snapshot(out) == before


def test_trees_replaces_an_earlier_gallery_whole(tmp_path, capsys, one_archetype):
    from mitsuforest.cli import main
    out = tmp_path / "gallery"
    _earlier_files(out, ["tree01_wood.ply", "tree07_leaves.ply", "repairs.csv", "notes.txt"])
    assert main(["trees", "-o", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "tree01_leaves.ply", "tree01_wood.ply",
                                                     "trees.png", "volumes.csv"]
    assert (out / "tree01_wood.ply").read_bytes().startswith(b"ply")


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "tiny.yaml"
    path.write_text(SCENE)
    return path


def test_export_interrupted_leaves_the_folder_as_it_was(tmp_path, capsys, monkeypatch, tiny_scene):
    """Ctrl-C at the fifth OBJ: an earlier export's meshes and documents stay as they were, no new one."""
    from mitsuforest.cli import main
    from mitsuforest.helios import export
    out = tmp_path / "export"
    before = _earlier_files(out, ["tiny_models/tree01_c000_stem.obj", "tiny_helios_survey.xml", "other.txt"])
    monkeypatch.setattr(export, "write_obj", _failing_on_call(5, KeyboardInterrupt(), export.write_obj))
    assert main(["export", str(tiny_scene), "-o", str(out)]) == 130
    assert "no finished output was written (partial files removed)" in capsys.readouterr().err
    assert _snapshot(out) == before


def test_export_on_a_full_disk_names_the_file(tmp_path, capsys, monkeypatch, tiny_scene):
    """The third OBJ cannot be written: one line names it (where it would have been), exit 1, and
    nothing new is left."""
    from mitsuforest.cli import main
    out = tmp_path / "export"
    real = Path.write_text

    def write_text(self, text, *args, **kwargs):
        if ".obj" in self.name and len(written) == 2:
            raise ENOSPC
        written.append(self.name) if ".obj" in self.name else None
        return real(self, text, *args, **kwargs)
    written = []
    monkeypatch.setattr(Path, "write_text", write_text)
    assert main(["export", str(tiny_scene), "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"mitsuforest: {out}/tiny_models/tree")
    assert err[-1].endswith(".obj: No space left on device; nothing was finished (partial files removed)")
    assert _snapshot(out) == {}


def test_export_replaces_an_earlier_export_whole(tmp_path, capsys, tiny_scene):
    """A second export replaces the meshes' folder (a mesh of the earlier one is not left behind) and
    its documents name the final paths."""
    from mitsuforest.cli import main
    out = tmp_path / "export"
    _earlier_files(out, ["tiny_models/tree77_c000_stem.obj", "other.txt"])
    assert main(["export", str(tiny_scene), "-o", str(out)]) == 0
    meshes = sorted(p.name for p in (out / "tiny_models").iterdir())
    assert "tree77_c000_stem.obj" not in meshes and "ground.obj" in meshes and "materials.mtl" in meshes
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
    scene_xml = (out / "tiny_helios_scene.xml").read_text()
    assert f"{out}/tiny_models/ground.obj" in scene_xml and ".partial-" not in scene_xml
    assert (out / "other.txt").read_text() == "earlier"
