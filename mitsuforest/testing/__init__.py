"""Reference scenes for the tests and benchmarks, run through the real pipeline (:mod:`.analytic`).

Above the stages: it may import any of them, and no stage imports it.
"""
