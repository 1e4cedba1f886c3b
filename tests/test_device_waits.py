"""The scan's waits for the device leave Python's lock to the host's other threads (scan/kernel.py,
``evaluate_and_wait``): on a GPU the host places, labels and writes the last batch while the device
traces the next, which a wait that holds the lock would stop."""

import threading
import time

import pytest

from mitsuforest.scene.variant import available_variants

pytestmark = pytest.mark.skipif("llvm_ad_mono" not in available_variants(), reason="needs llvm_ad_mono")


class Spinner:
    """A thread that counts while it holds Python's lock: how far it got says how long it had it."""

    def __init__(self):
        self.count, self._stop = 0, False
        self._thread = threading.Thread(target=self._spin, daemon=True)

    def _spin(self):
        while not self._stop:
            self.count += 1

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop = True
        self._thread.join()

    def rate(self, seconds: float = 0.2) -> float:
        """Counts a second with the lock to itself."""
        start, t = self.count, time.perf_counter()
        time.sleep(seconds)
        return (self.count - start) / (time.perf_counter() - t)

    def share_during(self, rate: float, action, *args) -> float:
        """The share of ``action(*args)``'s wall time that this thread ran, at ``rate``."""
        start, t = self.count, time.perf_counter()
        action(*args)
        return (self.count - start) / rate / (time.perf_counter() - t)


def _slow_mask():
    """A lazy mask whose kernel takes a few hundred milliseconds on two cores."""
    import drjit as dr
    import mitsuba as mi
    x = dr.arange(mi.Float, 8_000_000)
    for _ in range(40):
        x = dr.sin(x) * 1.0001 + dr.cos(x)
    return x > 0.5


def test_a_wait_for_the_device_leaves_python_to_the_other_threads(llvm_mono):
    import drjit as dr

    threads = dr.thread_count()
    dr.set_thread_count(2)        # a render's pool runs kernels apart from the caller (a dataset worker may set 1)
    try:
        held, waited = _shares_of_the_lock()
    finally:
        dr.set_thread_count(threads)
    assert held < 0.2 and waited > 0.4, (held, waited)    # measured 0.05-0.09 and 0.73-0.79 on 2 cores


def _shares_of_the_lock() -> tuple[float, float]:
    """The share of a wait for a slow kernel that another Python thread ran: with a read-back alone, and
    with :func:`evaluate_and_wait` first."""
    import drjit as dr
    from mitsuforest.scan.kernel import evaluate_and_wait

    with Spinner() as spinner:
        evaluate_and_wait(_slow_mask())               # compiles both kernels
        dr.compress(_slow_mask())
        rate = spinner.rate()

        def compress_after_the_wait(mask):
            evaluate_and_wait(mask)
            dr.compress(mask)

        def compress_alone(mask):                     # a read-back waits for the kernel holding the lock
            dr.eval(mask)
            dr.compress(mask)

        waited = spinner.share_during(rate, compress_after_the_wait, _slow_mask())
        held = spinner.share_during(rate, compress_alone, _slow_mask())
    return held, waited
