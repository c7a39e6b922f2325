"""Start and stop `ehactl canbus hub` for tests (shared by the CAN tests)."""
import contextlib
import os
import pathlib
import subprocess

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("EHACTL_BIN", str(REPO / "target" / "release" / "ehactl"))


@contextlib.contextmanager
def hub(*extra):
    """Run a hub on a free port; yields (process, port). The hub prints exactly one line
    `listening on 127.0.0.1:PORT` on stdout at start."""
    proc = subprocess.Popen(
        [BIN, "canbus", "hub", "--listen", "127.0.0.1:0", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        assert line.startswith("listening on 127.0.0.1:"), (line, proc.stderr.read() if proc.poll() is not None else "")
        port = int(line.strip().rsplit(":", 1)[1])
        yield proc, port
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
