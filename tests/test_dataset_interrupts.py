"""`mitsuforest dataset` stopped (Ctrl-C, SIGTERM) or failing on a full disk: one line, no worker
tracebacks, and the index lists every plot finished so far.

The in-process tests run the embedded LocalCluster with its worker as a thread of this process, so that
a task can be replaced by one that fails.
"""

import csv
import errno
import io
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import ROOT
from helpers import tiny_scene

BASE = tiny_scene(1, 1, 0, 0, 0, output="{formats: [laz]}")


def _dataset_file(folder: Path, plots: int) -> Path:
    (folder / "base.yaml").write_text(BASE)
    path = folder / "set.yaml"
    path.write_text(f"base: base.yaml\nplots: {plots}\n")
    return path


def _index_plots(out: Path) -> list[str]:
    with open(out / "index.csv", newline="") as f:
        return [r["id"] for r in csv.DictReader(f) if r["kind"] == "plot"]


def _finished_plot(root, name: str) -> dict:
    """What a plot's task leaves, in small: one point file and the record listing it."""
    from mitsuforest.dataset import files
    folder = files.plot_folder(root, name)
    folder.mkdir(parents=True)
    (folder / f"{name}.laz").write_bytes(name.encode())
    record = {"plot": name, "scene_sha256": files.sha256(files.scene_file(root, name)),
              "files": files.checksums(root, [folder / f"{name}.laz"]), "points": 1, "classes": {"2": 1},
              "pulses": 1, "tiles": []}
    files.write_record(root, name, record)
    return record


@pytest.fixture
def threaded_cluster(monkeypatch):
    """The embedded LocalCluster with its workers as threads of this process."""
    import dask.distributed
    real = dask.distributed.LocalCluster

    def local_cluster(**options):
        return real(**{**options, "processes": False})
    monkeypatch.setattr(dask.distributed, "LocalCluster", local_cluster)


def test_ctrl_c_indexes_every_plot_with_a_record_and_says_how_many_are_kept(tmp_path, capfd, monkeypatch,
                                                                               threaded_cluster):
    """Ctrl-C as the client takes the second plot's result: both plots have their records (made by a
    stand-in task), so both are kept and indexed (the index used to miss the one the client had not
    taken), and the message says so in one line; the third plot never finished."""
    from mitsuforest.cli import main
    from mitsuforest.dataset import runner, tasks
    from mitsuforest.dataset.files import valid_record
    real_values = runner._with_values

    def render_plot(root, name, *args):
        if name == "plot_0002":
            raise RuntimeError("not this one")
        return _finished_plot(root, name)

    taken = []

    def with_values(record, dataset):
        taken.append(record["plot"])
        if len(taken) == 2:
            raise KeyboardInterrupt
        return real_values(record, dataset)
    monkeypatch.setattr(tasks, "render_plot", render_plot)
    monkeypatch.setattr(runner, "_with_values", with_values)
    out = tmp_path / "out"
    code = main(["dataset", str(_dataset_file(tmp_path, 3)), "-o", str(out), "--workers", "1", "--quiet"])
    err = capfd.readouterr().err.strip()
    assert code == 130, err
    assert err.splitlines() == [f"mitsuforest: interrupted; 2 of 3 plots finished and kept, listed in "
                                f"{out / 'index.csv'}. Run the same command again to render the rest."]
    assert _index_plots(out) == ["plot_0000", "plot_0001"]
    assert valid_record(out, "plot_0001") is not None and valid_record(out, "plot_0002") is None


def test_ctrl_c_before_any_plot_finished(tmp_path, capfd, monkeypatch, threaded_cluster):
    from mitsuforest.cli import main
    from mitsuforest.dataset import runner

    def interrupted(*args):
        raise KeyboardInterrupt
    monkeypatch.setattr(runner, "_run", interrupted)
    out = tmp_path / "out"
    assert main(["dataset", str(_dataset_file(tmp_path, 2)), "-o", str(out), "--workers", "1", "--quiet"]) == 130
    assert capfd.readouterr().err.strip().splitlines() == [
        "mitsuforest: interrupted; none of the 2 plots finished. Run the same command again to render the rest."]
    assert _index_plots(out) == []


def test_full_disk_on_a_worker_is_one_line(tmp_path, capfd, monkeypatch, threaded_cluster):
    """A worker's write failing (ENOSPC): the plot fails, reported once by the client, with the file;
    Dask's "Compute Failed" log with the worker's traceback is not shown."""
    from mitsuforest.cli import main
    from mitsuforest.dataset import tasks

    def render_plot(root, name, *args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), f"{root}/plots/{name}/{name}.laz")
    monkeypatch.setattr(tasks, "render_plot", render_plot)
    shown = logging.StreamHandler(io.StringIO())   # as Dask's own handler to stderr: silence_logs sets its level
    logging.getLogger("distributed").addHandler(shown)
    out = tmp_path / "out"
    try:
        code = main(["dataset", str(_dataset_file(tmp_path, 2)), "-o", str(out), "--workers", "1", "--quiet"])
    finally:
        logging.getLogger("distributed").removeHandler(shown)
    assert code == 1
    assert "Compute Failed" not in shown.stream.getvalue() and "Traceback" not in shown.stream.getvalue()
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1, "\n".join(err)
    assert err[0].startswith("mitsuforest: 2 of 2 plots failed (first: plot_0000: OSError: [Errno 28] No space "
                             f"left on device: '{out}/plots/plot_0000/plot_0000.laz')")


@pytest.mark.slow
@pytest.mark.parametrize("sig, code, word", [(signal.SIGINT, 130, "interrupted"),
                                             (signal.SIGTERM, 143, "stopped (SIGTERM)")])
def test_signal_to_the_whole_command_prints_no_worker_traceback(tmp_path, sig, code, word):
    """Ctrl-C in a terminal reaches the client and every worker process (one process group): the
    workers leave it to the client, which prints one line."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "mitsuforest", "dataset", str(_dataset_file(tmp_path, 6)), "-o", str(out),
           "--workers", "2", "--quiet"]
    proc = subprocess.Popen(cmd, cwd=ROOT, start_new_session=True, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 240
    while not list(out.glob("plots/*/*_dataset.json")) and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    os.killpg(proc.pid, sig)
    err = proc.communicate(timeout=120)[1].strip()
    assert proc.returncode == code
    assert len(err.splitlines()) == 1 and err.startswith(f"mitsuforest: {word}; "), err
    kept = int(err.split("; ")[1].split(" of ")[0])
    assert kept >= 1 and len(_index_plots(out)) == kept
