"""mitsuforest.torch.TileDataset over a dataset folder laid out as `mitsuforest dataset` writes it
(index.csv, splits.json, scenes/, tiles in PCD and LAZ): one split's tiles only, the right labels."""

import numpy as np
import pytest
import yaml

torch = pytest.importorskip("torch", reason="torch is the optional extra mitsuforest[torch]")

from mitsuforest.dataset import files  # noqa: E402
from mitsuforest.scan import POINT_DTYPE  # noqa: E402
from mitsuforest.torch import TileDataset  # noqa: E402
from mitsuforest.write.ground import fill_height, with_room_for_height  # noqa: E402
from mitsuforest.write.las import write_las  # noqa: E402
from mitsuforest.write.pcd import pcd_header  # noqa: E402

OFFSET = np.array([500_000.0, 6_000_000.0, 40.0])


def _tile_points(rng, n, x0, y0, label_base):
    p = np.zeros(n, POINT_DTYPE)
    p["x"], p["y"] = x0 + rng.uniform(0, 10, n), y0 + rng.uniform(0, 10, n)
    p["z"] = rng.uniform(0, 20, n)
    p["classification"] = label_base + np.arange(n) % 3
    p["instance"] = np.arange(n)
    p["return_number"] = p["number_of_returns"] = 1
    return fill_height(p, with_room_for_height(p), lambda x, y: np.full(len(x), 0.5))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Plot a (georeferenced, PCD tiles, two tiles of 500 and 30 points) in train; plot b (local
    frame, LAZ tiles, one of 200 points) in test."""
    root = tmp_path_factory.mktemp("ds")
    rng = np.random.default_rng(1)
    truth, records = {}, []
    for plot, offset, fmt, sizes, base in (("plot_a", OFFSET, "pcd", (500, 30), 1), ("plot_b", None, "laz", (200,), 4)):
        scene = {"name": plot, **({"origin": {"offset": offset.tolist()}} if offset is not None else {})}
        (root / "scenes").mkdir(exist_ok=True)
        (root / "scenes" / f"{plot}.yaml").write_text(yaml.safe_dump(scene))
        tiles_dir = root / "plots" / plot / "tiles"
        tiles_dir.mkdir(parents=True)
        tiles = []
        for i, n in enumerate(sizes):
            tile = f"{plot}_x{i}_y0"
            local = _tile_points(rng, n, 10.0 * i, 0.0, base)
            geo = local.copy()
            if offset is not None:
                for axis, o in zip("xyz", offset):
                    geo[axis] += o
            path = tiles_dir / f"{tile}.{fmt}"
            if fmt == "pcd":
                path.write_bytes(pcd_header(geo.dtype, n).encode("ascii") + geo.tobytes())
            else:
                write_las(path, geo, offset if offset is not None else [0.0, 0.0, 0.0])
            truth[tile] = local
            tiles.append({"tile": tile, "core": [10.0 * i, 0.0, 10.0 * (i + 1), 10.0], "points": n,
                          "core_points": n, "trees": 0, "classes": {}, "files": files.checksums(root, [path])})
        records.append({"plot": plot, "points": sum(sizes), "classes": {}, "files": {}, "values": {}, "tiles": tiles})
    splits = {"train": ["plot_a"], "validation": [], "test": ["plot_b"]}
    files.write_json(root / "splits.json", splits)
    files.write_index(root, records, (), splits)
    return root, truth


def test_one_split_only_with_the_right_points_and_labels(dataset):
    root, truth = dataset
    train = TileDataset(root, "train", fields=("x", "y", "z", "height_above_ground"), points=100, seed=3)
    assert [t["id"] for t in train.tiles] == ["plot_a_x0_y0", "plot_a_x1_y0"]
    for i in range(len(train)):
        item = train[i]
        local = truth[item["tile"]]
        rows = item["index"].numpy()
        assert item["points"].shape == (100, 4) and item["points"].dtype == torch.float32
        assert np.array_equal(item["labels"].numpy(), local["classification"][rows].astype(np.int64))
        centre_x = 5.0 + 10.0 * i
        assert np.allclose(item["points"][:, 0].numpy(), local["x"][rows] - centre_x, atol=1e-4)
        assert np.allclose(item["points"][:, 2].numpy(), local["z"][rows], atol=1e-4)
        assert np.all(item["points"][:, 3].numpy() == np.float32(local["z"][rows] - 0.5))
    assert len(np.unique(train[0]["index"].numpy())) == 100          # 500 points: without replacement
    assert set(train[1]["index"].numpy()) == set(range(30))           # 30 points: each at least once
    assert np.array_equal(train[0]["index"].numpy(), train[0]["index"].numpy())   # seeded: repeatable
    test = TileDataset(root, "test", label="instance", points=None)
    assert len(test) == 1 and test[0]["tile"] == "plot_b_x0_y0"       # LAZ, local frame
    assert np.array_equal(test[0]["labels"].numpy(), np.arange(200))
    assert np.allclose(test[0]["points"][:, 1].numpy(), truth["plot_b_x0_y0"]["y"] - 5.0, atol=1e-4)
    assert len(TileDataset(root, "validation")) == 0


def test_a_plain_dataloader_batches_it_with_a_transform(dataset):
    root, _ = dataset

    def flip(item):
        item["points"][:, 0] *= -1
        return item
    tiles = TileDataset(root, "train", points=64, transform=flip, seed=0)
    plain = TileDataset(root, "train", points=64, seed=0)
    batch = next(iter(torch.utils.data.DataLoader(tiles, batch_size=2)))
    assert batch["points"].shape == (2, 64, 3) and batch["labels"].shape == (2, 64)
    assert batch["tile"] == ["plot_a_x0_y0", "plot_a_x1_y0"]
    assert torch.equal(batch["points"][0, :, 0], -plain[0]["points"][:, 0])


def test_bad_split_and_field_are_named(dataset):
    root, _ = dataset
    with pytest.raises(ValueError, match="no split 'val'"):
        TileDataset(root, "val")
    with pytest.raises(ValueError, match="no field reflectivity"):
        TileDataset(root, "train", fields=("x", "reflectivity"))[0]
