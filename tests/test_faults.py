"""Hostile values that used to pass validation and crash (or run for minutes) later: each is refused
up front with one line naming the file, key and reason, exit 2, nothing written, within a second."""

import time

import pytest
from test_config import GOOD

from mitsuforest.cli import main

LEG = "lines: [[[5, -2], [5, 12]]]"
HOSTILE = {
    "nan trees": (GOOD.replace("trees: 1", "trees: .nan"), [], "forest.trees: must be finite, got nan"),
    "nan seed": ("seed: .nan\n" + GOOD, [], "seed: must be finite, got nan"),
    "infinite bushes": (GOOD.replace("bushes: 0", "bushes: .inf"), [], "understory.bushes: must be finite, got inf"),
    "negative seed": (GOOD, ["--seed", "-1"], "seed: must be >= 0, got -1"),
    "scalar variant": (GOOD, ["--variant", "scalar_rgb"], "simulation.variant: must be auto or a Mitsuba llvm_*"),
    "slow flight": (GOOD.replace("altitude: 30", "altitude: 30, speed: 1e-4"), [],
                    "survey.speed: leg 1 lasts"),
    "huge plot": (GOOD.replace("size: [10, 10]", "size: [1e6, 1e6]"), [], "area.size[0]: must be <= 2000, got 1e+06"),
    "duplicate key": (GOOD + "seed: 3\nseed: 4\n", [], "duplicate key 'seed'"),
    "zero-length leg": (GOOD.replace("altitude: 30", "altitude: 30, lines: [[[5, 5], [5, 5]]]"), [],
                        "survey.lines[0]: a leg needs two distinct ends"),
    "leg far away": (GOOD.replace("altitude: 30", "altitude: 30, lines: [[[5000, 0], [5000, 10]]]"), [],
                     "survey.lines[0]: the leg passes 4,990.0 m from the plot"),
    "too many trees": (GOOD.replace("trees: 1", "trees: 100000"), [], "forest.trees: 100000 trees at min_spacing"),
    "tiny batches": (GOOD + "simulation: {pulses_per_batch: 1}\n", [],
                     "simulation.pulses_per_batch: must be >= 1000, got 1"),
    "too many bushes": (GOOD.replace("bushes: 0", "bushes: 5000"), [], "understory.bushes: 5000 bushes do not fit"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_value_is_refused_at_once(case, tmp_path, monkeypatch, capsys):
    import mitsuforest.render  # noqa: F401  (imports are not what is timed)
    text, args, message = HOSTILE[case]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scene.yaml").write_text(text)
    start = time.perf_counter()
    code = main(["render", "scene.yaml", "-o", "out", *args])
    seconds = time.perf_counter() - start
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert err.count("\n") == 0 and err.startswith("mitsuforest: scene.yaml: ") and message in err, err
    assert not (tmp_path / "out").exists()
    assert seconds < 1.0
