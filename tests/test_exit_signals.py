"""A signal that arrives after the command has ended, while the interpreter shuts down (threads
joining, exit handlers running), ends the process with one line and the usual code."""

import signal
import subprocess
import sys

import pytest

from conftest import ROOT

# `python -m mitsuforest info missing.pcd` (exit 2 at once) with an exit handler that takes its time, as
# Dask's or Dr.Jit's may: it says "ready" and waits for the signal.
PROGRAM = """
import atexit, runpy, sys, time
atexit.register(lambda: (print("ready", flush=True), time.sleep(60)))
sys.argv = ["mitsuforest", "info", "missing.pcd"]
runpy.run_module("mitsuforest", run_name="__main__")
"""


@pytest.mark.parametrize("sig, code, word", [(signal.SIGINT, 130, "interrupted"),
                                             (signal.SIGTERM, 143, "stopped (SIGTERM)")])
def test_a_signal_during_teardown_exits_with_one_line(tmp_path, sig, code, word):
    proc = subprocess.Popen([sys.executable, "-c", PROGRAM], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == code
    assert err.strip().splitlines() == ["mitsuforest: missing.pcd: file not found",
                                        f"mitsuforest: {word} while exiting, after the command had ended"]



# `main` called with arguments (as a library would) leaves the collector alone. Run as the program
# (argv None), it freezes what its heavy imports made before the command runs, and what the command
# leaves before the interpreter exits, so that the collector's passes skip them.
FREEZE = """
import gc, sys
import mitsuforest.cli as cli
seen = []
cli._COMMANDS["plan"] = lambda args: seen.append(gc.get_freeze_count())
cli.main(["plan", "scenes/demo.yaml"])
cli.main(["info", "missing.pcd"])
print(seen[-1], gc.get_freeze_count())
sys.argv = ["mitsuforest", "info", "missing.pcd"]    # no heavy imports: frozen at its end only
cli.main()
print(gc.get_freeze_count())
gc.unfreeze()
sys.argv = ["mitsuforest", "plan", "scenes/demo.yaml"]
cli.main()
print(seen[-1])
"""


def test_the_program_leaves_long_lived_objects_out_of_the_collectors_passes():
    done = subprocess.run([sys.executable, "-c", FREEZE], cwd=ROOT, capture_output=True, text=True, timeout=60)
    as_library, at_the_end, before_the_command = done.stdout.splitlines()
    assert as_library == "0 0"
    assert int(at_the_end) > 10_000           # all the objects alive as the command ended
    assert int(before_the_command) > 50_000   # the heavy imports' modules: numpy, scipy, Mitsuba ...
