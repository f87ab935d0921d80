"""Lab Streaming Layer on the loopback interface without multicast: a liblsl configuration naming 127.0.0.1 as
the only known peer, set (``LSLAPICFG``) before liblsl's first call in the process, and an inlet that records
whole streams in a thread."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np
import pylsl
from pylsl.util import LostError

CONFIG = """[ports]
IPv6 = disable
[multicast]
ResolveScope = machine
KnownPeers = {127.0.0.1}
[log]
level = -2
"""


def loopback_config(folder: Path) -> Path:
    """Write the configuration and point liblsl at it (this process; liblsl reads it once, at its first call)."""
    path = Path(folder) / "lsl_api.cfg"
    path.write_text(CONFIG)
    os.environ["LSLAPICFG"] = str(path)
    return path


class Recorder(threading.Thread):
    """Resolve the streams with the given source ids, connect to each, and pull everything until :meth:`stop`."""

    def __init__(self, source_ids: list[str], timeout_s: float = 30.0) -> None:
        super().__init__(daemon=True, name="lsl-recorder")
        self.source_ids, self.timeout_s = source_ids, timeout_s
        self.data = {sid: ([], []) for sid in source_ids}
        self.connected = threading.Event()
        self.offsets: dict = {}
        self.error: str | None = None
        self._halt = threading.Event()

    def run(self) -> None:
        try:
            inlets = {}
            pred = " or ".join(f"source_id='{sid}'" for sid in self.source_ids)
            found = {i.source_id(): i for i in pylsl.resolve_bypred(pred, len(self.source_ids), self.timeout_s)}
            for sid in self.source_ids:
                if sid not in found:
                    self.error = f"stream {sid} not found"
                    return
                # no recovery: a stream ends with its process (a recovering inlet would wait for it to come back)
                inlet = pylsl.StreamInlet(found[sid], max_buflen=360, recover=False)
                inlet.open_stream(self.timeout_s)
                self.offsets[sid] = inlet.time_correction(self.timeout_s)   # while the outlet is there
                inlets[sid] = inlet
            self.connected.set()
            while True:
                stopping = self._halt.is_set()
                for sid, inlet in list(inlets.items()):
                    try:
                        values, stamps = inlet.pull_chunk(timeout=0.05, max_samples=100_000)
                    except LostError:    # its process ended: everything it sent has been pulled
                        del inlets[sid]
                        continue
                    self.data[sid][0].extend(values)
                    self.data[sid][1].extend(stamps)
                if stopping:
                    break
        except Exception as exc:   # reported by the test
            self.error = repr(exc)

    def stop(self, drain_s: float = 1.0) -> None:
        """Pull what is still in flight for ``drain_s``, then end."""
        threading.Event().wait(drain_s)
        self._halt.set()
        self.join(30.0)

    def stream(self, sid: str) -> tuple[list, np.ndarray]:
        values, stamps = self.data[sid]
        return values, np.asarray(stamps, dtype=float)
