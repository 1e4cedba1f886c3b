"""Choosing the Mitsuba variant (CPU: llvm_ad_mono, GPU: cuda_ad_mono).

The stages that need Mitsuba run under :func:`variant_scope`, which sets the variant for the block and
puts back the one it found, so scenes of two variants can live in one process (the tests run both where
a GPU is present). Mitsuba's variant is one per process, and Mitsuba 3.9 has no way back to "no variant"
(``set_variant`` takes variant names only), so a process's first scope leaves its variant set.
"""

from __future__ import annotations

import glob
from contextlib import contextmanager
import os
import re

from ..errors import UserError
from ..interrupts import held_while_loading

LLVM_HELP = ("Dr.Jit needs libLLVM >= 17 for the CPU backend (LLVM 15/16 abort with 'Cannot select "
             "fminimum'). Install it with: apt-get install -y libllvm19")


def _llvm_versions() -> list[int]:
    paths = glob.glob("/usr/lib/*/libLLVM*.so*") + glob.glob("/usr/lib/llvm-*/lib/libLLVM*.so*") + \
        glob.glob("/usr/local/lib/libLLVM*.so*")
    found = {int(m.group(1)) for p in paths if (m := re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", os.path.basename(p)))}
    return sorted(found)


def check_llvm() -> None:
    """Refuse to start the CPU backend with an LLVM that would abort the process."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return
    versions = _llvm_versions()
    if versions and max(versions) < 17:
        raise UserError(f"only libLLVM {max(versions)} found. {LLVM_HELP}")


def llvm_available() -> bool:
    """Whether Dr.Jit's CPU backend can start (a usable libLLVM was found)."""
    if not os.environ.get("DRJIT_LIBLLVM_PATH") and _llvm_versions() and max(_llvm_versions()) < 17:
        return False
    try:
        import drjit as dr
        return bool(dr.has_backend(dr.JitBackend.LLVM))
    except Exception:  # no libLLVM at all
        return False


def cuda_available() -> bool:
    try:
        import drjit as dr
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # no driver, no device
        return False


def available_variants() -> list[str]:
    """The mono variants this machine can run: ``llvm_ad_mono`` (with a usable libLLVM), and
    ``cuda_ad_mono`` when a GPU is usable."""
    import mitsuba as mi
    out = []
    if "llvm_ad_mono" in mi.variants() and llvm_available():
        out.append("llvm_ad_mono")
    if "cuda_ad_mono" in mi.variants() and cuda_available():
        out.append("cuda_ad_mono")
    return out


class VariantError(UserError):
    """A ``simulation.variant`` this machine cannot run (see :func:`scene_variant`, which names the file)."""

    def __init__(self, reason: str):
        self.reason = reason
        super().__init__(f"simulation.variant: {reason}")

    def __reduce__(self):   # pickled whole (Dask sends a worker's errors to the client)
        return type(self), (self.reason,)


def select_variant(requested: str = "auto") -> str:
    """The variant to run, checked: ``auto`` prefers ``cuda_ad_mono`` when a GPU is usable.

    :raises VariantError: a variant not in this Mitsuba build, or a CUDA one without a usable GPU.
    """
    import mitsuba as mi
    variant = requested
    if requested == "auto":
        variant = "cuda_ad_mono" if cuda_available() else "llvm_ad_mono"
    if variant not in mi.variants():
        raise VariantError(f"{variant!r} is not in this Mitsuba build (available: {', '.join(mi.variants())})")
    if variant.startswith("llvm"):
        check_llvm()
    if variant.startswith("cuda") and not cuda_available():
        raise VariantError(f"{variant} needs a CUDA GPU, and none is usable here")
    return variant


def scene_variant(scene) -> str:
    """The variant a :class:`~mitsuforest.config.types.Scene` runs under (:func:`select_variant`); one
    this machine cannot run is refused like the scene file's own errors, ``FILE: simulation.variant: ...``."""
    from ..config import scene_error
    try:
        return select_variant(scene.simulation.variant)
    except VariantError as e:
        raise scene_error(scene, "simulation.variant", e.reason) from None


@contextmanager
def variant_scope(variant: str):
    """Run a block under a Mitsuba variant and put back the variant found, also when the block fails.

    With no variant set before (a process's first scope), the block's variant stays set: Mitsuba 3.9
    cannot unset one (``set_variant(None)`` fails, which is why ``mi.variant_context`` fails on exit
    then).
    """
    import mitsuba as mi
    previous = mi.variant()
    _set_variant(variant)
    try:
        yield
    finally:
        if previous is not None:
            mi.set_variant(previous)


def _set_variant(variant: str) -> None:
    """``mi.set_variant``, the first time with signals held: it imports the variant's C extension, which
    an interrupt landing half-way leaves broken (``SystemError: __import__ returned a result with an
    exception set``)."""
    import mitsuba as mi
    with held_while_loading(f"mitsuba.{variant}"):
        mi.set_variant(variant)
