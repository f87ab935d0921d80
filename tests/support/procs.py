"""Process helpers of the stop-signal tests (Linux /proc)."""

import os
import signal


def running(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie (exited, not yet reaped)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def kill(pid: int) -> None:
    """SIGKILL ``pid`` if it still exists (cleanup after a test)."""
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
