"""The point formats' one registry (``fields.POINT_FORMATS``, ``write.formats.READERS``): names, suffixes,
and points written whole and read back by their file's name."""

import numpy as np
import pytest

from mitsuforest.fields import POINT_FORMATS
from mitsuforest.write import output_files
from mitsuforest.write.formats import READERS, format_of, read_points, write_points


def test_every_format_is_an_output_a_choice_and_a_reader():
    from mitsuforest.config import SCENE_SPEC
    assert set(SCENE_SPEC["output"]["formats"].item.choices) == set(POINT_FORMATS) == set(READERS)
    assert {"t" + suffix for suffix in POINT_FORMATS.values()} <= set(output_files("t"))


@pytest.mark.parametrize("name, fmt", [("a.pcd", "pcd"), ("A.LAS", "las"), ("a.laz", "laz"), ("a.copc.laz", "copc"),
                                       ("a_forinstance.laz", "laz"), ("a_trees.csv", None), ("a", None)])
def test_a_file_is_of_the_format_its_name_ends_with(name, fmt):
    assert format_of(name) == fmt


@pytest.mark.parametrize("fmt", ["pcd", "las", "laz"])
def test_points_written_whole_read_back_by_their_name(tmp_path, fmt):
    from mitsuforest.fields import RECORD_DTYPE
    rng = np.random.default_rng(4)
    points = np.zeros(500, RECORD_DTYPE)
    points["x"], points["y"], points["z"] = rng.uniform(0, 20, (3, 500))
    points["classification"], points["return_number"], points["number_of_returns"] = 3, 1, 1
    offset = (500000.0, 6000000.0, 10.0)
    for axis, o in zip("xyz", offset):
        points[axis] += o
    path = tmp_path / f"t{POINT_FORMATS[fmt]}"
    write_points(path, points, offset)
    back = read_points(path)
    assert len(back) == 500 and np.array_equal(back["classification"], points["classification"])
    assert np.abs(back["x"] - points["x"]).max() < 1e-4
    with pytest.raises(ValueError, match="not a point file"):
        read_points(tmp_path / "t.txt")
