"""Choosing and activating the Mitsuba variant (CPU: llvm_ad_mono, GPU: cuda_ad_mono)."""

from __future__ import annotations

import glob
import os
import re

from ..errors import UserError

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


def cuda_available() -> bool:
    try:
        import drjit as dr
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # no driver, no device
        return False


def select_variant(requested: str = "auto") -> str:
    """Activate and return the variant: ``auto`` prefers ``cuda_ad_mono`` when a GPU is usable."""
    import mitsuba as mi
    variant = requested
    if requested == "auto":
        variant = "cuda_ad_mono" if cuda_available() else "llvm_ad_mono"
    if variant not in mi.variants():
        raise UserError(f"simulation.variant: {variant!r} is not in this Mitsuba build "
                        f"(available: {', '.join(mi.variants())})")
    if variant.startswith("llvm"):
        check_llvm()
    if variant.startswith("cuda") and not cuda_available():
        raise UserError(f"simulation.variant: {variant} needs a CUDA GPU, and none is usable here")
    mi.set_variant(variant)
    return variant
