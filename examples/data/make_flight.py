"""Writes ``examples/data/flight.csv``, the trajectory of ``examples/flight.yaml``: two flight lines over
its 20 m plot, 8 m apart, flown north then south at 2 m/s and 30 m above the ground, 50 rows a second
(the rate of a typical exported INS solution), as a real platform flies them: a gentle S-curve across
the track, a crab angle into a wind from the west, and a roll and pitch wobble of about a degree. The
turn between the lines is left out (the ``line`` column), so the scanner is off there. Nothing random:
running it again writes the same rows. Run it from anywhere: ``python examples/data/make_flight.py``.
"""

from pathlib import Path

import numpy as np

RATE, SPEED, HEIGHT = 50.0, 2.0, 30.0   # rows a second, m/s, m above the flat ground


def line(number: int, x: float, y0: float, y1: float, t0: float) -> np.ndarray:
    """Rows time, x, y, z, roll, pitch, yaw, line of one flight line from (x, y0) to (x, y1)."""
    duration = abs(y1 - y0) / SPEED
    t = np.arange(0.0, duration + 1e-9, 1 / RATE)
    heading = 0.0 if y1 > y0 else 180.0
    y = y0 + np.sign(y1 - y0) * SPEED * t
    rows = np.column_stack([
        t0 + t,
        x + 0.6 * np.sin(2 * np.pi * t / duration),                  # S-curve: up to 0.6 m off the line
        y,
        HEIGHT + 0.3 * np.sin(2 * np.pi * t / 7.0),                   # +-0.3 m in height
        1.2 * np.sin(2 * np.pi * t / 2.3),                            # roll (deg)
        2.0 + 0.8 * np.sin(2 * np.pi * t / 3.1 + 1.0),                # pitch: 2 deg nose up, +-0.8
        (heading - 4.0 + 1.5 * np.sin(2 * np.pi * t / 5.0)) % 360,    # crab 4 deg into the wind
        np.full(len(t), number)])
    return rows


def main(path=Path(__file__).with_name("flight.csv")) -> Path:
    rows = np.vstack([line(1, 6.0, -6.0, 26.0, 100.0), line(2, 14.0, 26.0, -6.0, 130.0)])
    text = "time,x,y,z,roll,pitch,yaw,line\n" + "".join(
        f"{r[0]:.3f},{r[1]:.4f},{r[2]:.4f},{r[3]:.4f},{r[4]:.4f},{r[5]:.4f},{r[6]:.4f},{r[7]:.0f}\n" for r in rows)
    Path(path).write_text(text)
    return Path(path)


if __name__ == "__main__":
    print(f"wrote {main()}")
