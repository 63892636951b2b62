"""`WbmpcProcess`: a `wbmpc` command run as a child process of a test, on this checkout's sources.

Its output goes to temporary files, not pipes: a pipe the test reads only at the end can fill (robot-sim's
report holds its trajectory), block the child and, through its stalled DDS reader, the test's own
DataWriter.write; the suite hung on that once. Importable from any test module (pytest puts tests/ on the
path through its conftest.py)."""

import os
import subprocess
import sys
import tempfile

SRC = os.path.join(os.path.dirname(__file__), "..", "src")


class WbmpcProcess(subprocess.Popen):
    """`WbmpcProcess("robot-sim", "--robot", "go2", ...)` starts `python -m wbmpc.cli ARGS`."""

    def __init__(self, *args):
        env = dict(os.environ, PYTHONPATH=os.path.abspath(SRC) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self._stdout_file, self._stderr_file = tempfile.TemporaryFile("w+"), tempfile.TemporaryFile("w+")
        super().__init__([sys.executable, "-m", "wbmpc.cli", *args], env=env, stdout=self._stdout_file,
                         stderr=self._stderr_file, text=True)

    def communicate(self, input=None, timeout=None):
        self.wait(timeout)
        return self.read_output(), self.read_errors()

    def read_output(self) -> str:
        self._stdout_file.seek(0)
        return self._stdout_file.read()

    def read_errors(self) -> str:
        self._stderr_file.seek(0)
        return self._stderr_file.read()
