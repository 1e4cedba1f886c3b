"""mitsuforest: labelled UAV LiDAR scans of synthetic forests, on Mitsuba 3 / Dr.Jit.

The pipeline, one sub-package a stage: ``plan`` → ``trees`` → ``scene`` → ``scan`` → ``labels`` → ``write``.

>>> import mitsuforest as mf                                   # doctest: +SKIP
>>> scene = mf.load_scene("scenes/demo.yaml")                   # doctest: +SKIP
>>> scene["survey"]["altitude"] = 40                           # doctest: +SKIP
>>> result = mf.render(scene, write=False)                     # doctest: +SKIP
>>> result.points["x"], result.points["classification"]        # doctest: +SKIP
"""

__version__ = "0.1.0"

from .config import load_scene, load_sensor  # noqa: E402
from .errors import ConfigError, UserError  # noqa: E402
from .plan import make_plan  # noqa: E402
from .render import render  # noqa: E402
from .write import read_pcd  # noqa: E402

__all__ = ["load_scene", "load_sensor", "make_plan", "render", "read_pcd", "ConfigError", "UserError",
           "__version__"]
