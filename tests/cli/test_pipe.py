"""`bmctl ... | head`: a reader that leaves early ends the command quietly (exit 141, nothing on
stderr), as Unix tools do, instead of "error: output: Broken pipe"."""

import subprocess
import sys

from ..conftest import ROOT


def test_a_closed_output_pipe_is_quiet():
    p = subprocess.Popen([sys.executable, "-m", "bmctl", "card", "show", str(ROOT / "models" / "alni-1to1-300rpm-lab.toml")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
    p.stdout.close()  # the reader is gone before the command writes
    err = p.stderr.read().decode()
    assert p.wait() == 141 and err == "", err
