"""Ctrl-C ends every `finray` command with exit status 130 and one line, at any moment.

Each command runs as a real process of the installed console script (the compilation
cache off, so that compiling takes its full time) and gets a real SIGINT at three moments:
while Python imports jax and the package (0.1 s after the start), just
after the command announces its first compile (inside the compile), and at a later
point of its work (a progress line further on, or a second into the compile of a command
that has nothing after it). The process must end with 130 within the grace period, its
stderr must end in the one "finray: interrupted" line with no traceback, and a file the
line names must exist.
"""

import os
import pathlib
import re
import shutil
import signal
import subprocess
import sys
import threading
import time

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
FINRAY = shutil.which("finray", path=os.path.dirname(sys.executable))
GRACE = 5.0  # finray_cli.GRACE
START = (None, 0.1)  # during the imports (jax alone takes longer)
COMPILING = ("compiling the", 0.2)  # inside the first compile


def _commands(out: pathlib.Path):
    """(argv, the later moment: (marker on stderr, seconds after it)) per command."""
    return {
        "solve": (["solve", str(EXAMPLES / "ref_a.toml")], ("compiling the", 1.0)),
        "limit": (["limit", str(EXAMPLES / "ref_a.toml")], ("compiling the", 1.0)),
        "validate": (["validate", str(EXAMPLES / "ref_a.toml")], (None, 1.2)),
        "demo": (["demo", "--out", str(out)], ("compiling the contact solver", 0.5)),
        "grasp": (["grasp", str(EXAMPLES / "grasp_finger1.toml")], ("grasp, closing", 1.0)),
        "compare": (["compare", "--out", str(out)], ("modified adaptor", 0.5)),
        "clamp-study": (["clamp-study", "--out", str(out)], ("l_c =", 1.0)),
        "sweep": (
            ["sweep", str(EXAMPLES / "sweep_clamp.toml"), "--out", str(out)],
            ("compiling the batch solver", 1.5),
        ),
        "optimize": (
            ["optimize", str(EXAMPLES / "optimize_clamp.toml"), "--out", str(out)],
            ("grasp of object", 0.5),
        ),
    }


def _interrupt(argv, marker, delay, cwd):
    """Start finray argv, send SIGINT `delay` s after `marker` shows on stderr (or after
    the start), wait for the end: (exit status, stdout, stderr, whether the signal went)."""
    env = dict(os.environ, FINRAY_NO_CACHE="1", PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [FINRAY, *argv],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    err_lines, seen = [], threading.Event()

    def read_stderr():
        for line in proc.stderr:
            err_lines.append(line)
            if marker is not None and marker in line:
                seen.set()

    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    if marker is None or seen.wait(timeout=300):
        time.sleep(delay)
    sent = proc.poll() is None
    if sent:
        proc.send_signal(signal.SIGINT)
        t_sent = time.perf_counter()
    out = proc.stdout.read()
    code = proc.wait(timeout=120)
    reader.join(timeout=10)
    if sent:
        assert time.perf_counter() - t_sent < GRACE + 5.0, "finray took too long to stop"
    return code, out, "".join(err_lines), sent


@pytest.mark.skipif(FINRAY is None, reason="the finray console script is not installed")
@pytest.mark.parametrize("moment", ["import", "compile", "work"])
@pytest.mark.parametrize(
    "command",
    ["solve", "limit", "validate", "demo", "grasp", "compare", "clamp-study", "sweep", "optimize"],
)
def test_ctrl_c_exits_130_with_one_line(command, moment, tmp_path):
    argv, later = _commands(tmp_path / "out")[command]
    marker, delay = {"import": START, "compile": COMPILING, "work": later}[moment]
    if command == "validate" and moment == "compile":  # (validate announces no compile:
        marker, delay = None, 0.7  # its rules compile in about 2 s, after the imports)
    code, out, err, sent = _interrupt(argv, marker, delay, tmp_path)
    assert sent, f"finray {command} ended before the {moment} moment:\n{err}"
    assert code == 130, f"exit {code}\n{err}"
    assert "Traceback" not in err and "Exception ignored" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines and lines[-1].startswith("finray: interrupted"), err
    assert sum("interrupted" in ln for ln in lines) == 1, err
    if moment == "import":
        assert out == "", out
    for named in re.findall(r" are in (\S+?):", lines[-1]):
        assert (tmp_path / named).exists() or pathlib.Path(named).exists(), named
