"""Agreement of two renders of one scene (e.g. CPU ``llvm_ad_mono`` against GPU ``cuda_ad_mono``), from
their manifests: points, points by class and pulses by their number of returns, each with its relative difference.

    python benchmarks/agreement.py out/open_cpu/open_manifest.json out/open_gpu/open_manifest.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from mitsuforest.classes import class_name


def rows(a: dict, b: dict) -> list[tuple[str, int, int]]:
    """(label, count in a, count in b) for the points, each class and each number of returns per pulse."""
    out = [("points", a["points"], b["points"])]
    for code in sorted({*a["classes"], *b["classes"]}, key=int):
        out.append((class_name(int(code)), a["classes"].get(code, 0), b["classes"].get(code, 0)))
    for n in sorted({*a["returns_histogram"], *b["returns_histogram"]}, key=int):
        out.append((f"pulses with {n} returns", a["returns_histogram"].get(n, 0), b["returns_histogram"].get(n, 0)))
    return out


def relative(a: int, b: int) -> str:
    return f"{(b - a) / a:+.4%}" if a else "–"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("a", type=Path, help="the first render's manifest (JSON)")
    p.add_argument("b", type=Path, help="the second render's manifest (JSON)")
    args = p.parse_args(argv)
    a, b = (json.loads(path.read_text()) for path in (args.a, args.b))
    print(f"| | {a['variant']} | {b['variant']} | difference |\n| --- | --- | --- | --- |")
    for label, x, y in rows(a, b):
        print(f"| {label} | {x:,} | {y:,} | {relative(x, y)} |")


if __name__ == "__main__":
    main()
