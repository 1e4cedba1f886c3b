"""mitsuforest: labelled UAV LiDAR scans of synthetic forests, on Mitsuba 3 / Dr.Jit.

The pipeline, one sub-package a stage: ``plan`` → ``trees`` → ``scene`` → ``scan`` → ``labels`` → ``write``.

>>> import mitsuforest as mf                                   # doctest: +SKIP
>>> scene = mf.load_scene("scenes/demo.yaml")                   # doctest: +SKIP
>>> scene = scene.with_({"survey.altitude": 40})                # doctest: +SKIP
>>> result = mf.render(scene, write=False)                     # doctest: +SKIP
>>> result.points["x"], result.points["classification"]        # doctest: +SKIP

The names below are imported on first use, so that ``python -m mitsuforest`` can hold interrupts
while the heavy libraries load (``interrupts.deferred_signals``).
"""

import importlib
import sys

__version__ = "0.1.0"

_API = {"load_scene": "config", "load_sensor": "config", "ConfigError": "errors", "UserError": "errors",
        "make_plan": "survey", "render": "pipeline", "read_pcd": "write"}

__all__ = [*_API, "__version__"]


def _imported_on_first_use(package: str, modules: dict[str, str]):
    """A module ``__getattr__`` for ``package``: ``name`` is imported from ``package.modules[name]`` on its
    first use and kept in the package."""
    def __getattr__(name):
        if name in modules:
            value = getattr(importlib.import_module(f".{modules[name]}", package), name)
            setattr(sys.modules[package], name, value)
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")
    return __getattr__


__getattr__ = _imported_on_first_use(__name__, _API)
