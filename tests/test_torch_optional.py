"""mitsuforest.torch without PyTorch installed: what it says, and its argument checks (on a stand-in
torch, so they run where the optional extra is not installed)."""

import importlib
import sys
import types

import pytest


@pytest.fixture
def fresh_module(monkeypatch):
    monkeypatch.delitem(sys.modules, "mitsuforest.torch", raising=False)
    yield
    sys.modules.pop("mitsuforest.torch", None)


def test_without_torch_the_import_says_how_to_install_it(monkeypatch, fresh_module):
    monkeypatch.setitem(sys.modules, "torch", None)          # import torch fails as when it is not installed
    with pytest.raises(ModuleNotFoundError, match=r"pip install 'mitsuforest\[torch\]'") as e:
        importlib.import_module("mitsuforest.torch")
    assert e.value.name == "torch"


@pytest.mark.parametrize("points", [0, -5, 2.5, True, "4096"])
def test_a_bad_sample_size_is_refused_before_any_file_is_read(monkeypatch, fresh_module, tmp_path, points):
    stand_in = types.ModuleType("torch")
    stand_in.utils = types.SimpleNamespace(data=types.SimpleNamespace(Dataset=object))
    monkeypatch.setitem(sys.modules, "torch", stand_in)
    tiles = importlib.import_module("mitsuforest.torch")
    with pytest.raises(ValueError, match=rf"points: the sample size must be a whole number >= 1 or None, got {points!r}"):
        tiles.TileDataset(tmp_path / "no such folder", points=points)
