"""Training datasets: many plots, or large plots split by flight leg, rendered on Dask.

>>> dataset = load_dataset("examples/dataset.yaml")            # doctest: +SKIP
>>> manifest = run_dataset(dataset, "out/dataset", workers=2)   # doctest: +SKIP

``spec`` reads a dataset file and draws one scene per plot; ``tiles`` cuts a plot's points into
square tiles (pure numpy); ``tasks`` is what the workers run; ``files`` writes records, tiles, the
index and the splits; ``parts`` is what a split plot's leg tasks leave for its merge and tile tasks;
``runner`` is the client (see README, "Datasets" and "Scaling out").
"""

from .runner import run_dataset
from .spec import Dataset, PlotSpec, Tiles, load_dataset

__all__ = ["Dataset", "PlotSpec", "Tiles", "load_dataset", "run_dataset"]
