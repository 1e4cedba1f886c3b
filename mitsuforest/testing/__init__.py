"""What the tests and benchmarks check the package against; nothing here runs in a render.

- :mod:`.reference`: the numpy twins of the scan's Dr.Jit stages (pulses, deflection, echoes and
  ``trace_reference``, the whole echo stage in numpy).
- :mod:`.analytic`: bare plots, planes and hand-made pulses run through the real pipeline.

It lives in the package, not in ``tests/``, because the benchmarks (``benchmarks/speed_vs_error.py``,
``benchmarks/stability.py``) use it too, and a user may use it to check a sensor setup. Above the
stages: it may import any of them, and no stage imports it (``tests/test_testing_package.py``).
"""
