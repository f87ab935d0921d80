"""Regenerate the Falcon contract vectors (``vectors/falcon_libnifalcon.json``) from libnifalcon itself.

Not a test: the contract test (``test_falcon_libnifalcon.py``) reads the file this writes. This script drives
an executable of the command-line harness in ``falcon_harness/`` (our code; its header lists the commands)
that the user has linked against libnifalcon's kinematics, firmware and loader, outside this repository, and
records, on seeded random inputs, what libnifalcon computes: inverse kinematics and Jacobian, force-to-motor
commands (``getForces``), encoder angles (``getTheta``), forward kinematics (``getPosition``, three calls per
point as libnifalcon starts from its previous answer), the 16-byte packets its firmware class writes and how it
reads the device's, and the blocks its firmware loader writes against exact and corrupted echoes.

    python tests/devices/hardware/contract/falcon_vectors.py --harness /path/to/falcon_harness \\
        --libnifalcon-commit <40 hex digits of the libnifalcon commit the harness was linked with> \\
        [--out tests/devices/hardware/contract/vectors/falcon_libnifalcon.json]

The inputs come from fixed seeds, so a harness linked with the same libnifalcon reproduces the file byte for
byte; ``vectors/README.md`` says which commit made the committed file and under which licence.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import random
import re
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[3]
if str(ROOT) not in sys.path:      # run as a script from anywhere: the project's packages are importable
    sys.path.insert(0, str(ROOT))

from devices.firmware.falcon_emulator import stand_in_firmware  # noqa: E402
from devices.hardware.falcon import kinematics as K  # noqa: E402
from devices.hardware.falcon import protocol as P  # noqa: E402

DEFAULT_OUT = HERE / "vectors" / "falcon_libnifalcon.json"
HARNESS_SOURCES = ("falcon_harness/falcon_harness.cpp", "falcon_harness/falcon/gmtl/gmtl.h")


class Harness:
    """The harness executable as a long-running process: ``ask(line) -> answer line``."""

    def __init__(self, exe: Path) -> None:
        self.proc = subprocess.Popen([str(exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     bufsize=1)

    def send(self, text: str) -> None:
        self.proc.stdin.write(text)
        self.proc.stdin.flush()

    def line(self) -> str:
        out = self.proc.stdout.readline()
        if not out:
            raise SystemExit(f"error: the harness stopped answering (exit code {self.proc.poll()})")
        return out.strip()

    def ask(self, line: str) -> str:
        self.send(line + "\n")
        return self.line()

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(10)


def points(n: int, seed: int) -> list[tuple[float, float, float]]:
    """Random positions (m) inside the Falcon's workspace (a 6 cm cube around its centre, reachable)."""
    rng = random.Random(seed)
    out = []
    while len(out) < n:
        p = (rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.08, 0.14))
        try:
            K.ik(p)
        except K.OutOfWorkspace:
            continue
        out.append(p)
    return out


def floats(line: str) -> list[float]:
    return [float(v) for v in line.split()]


def kinematics(h: Harness) -> dict:
    ik = []
    for p in points(200, 1):
        theta = floats(h.ask("ik %.17g %.17g %.17g" % p))
        jac = floats(h.ask("jac %.17g %.17g %.17g" % p))
        ik.append({"p": list(p), "theta": theta, "jacobian": jac})
    rng = random.Random(2)
    forces = []
    for p in points(300, 3):
        f = (rng.uniform(-9, 9), rng.uniform(-9, 9), rng.uniform(-9, 9))
        cmds = [int(v) for v in h.ask("forces %.17g %.17g %.17g %.17g %.17g %.17g" % (*p, *f)).split()]
        forces.append({"p": list(p), "force": list(f), "commands": cmds})
    # forces far beyond the Falcon's (kN): getForces scales the torques down together to its 30 N m cap
    rng = random.Random(7)
    for p in points(50, 8):
        f = (rng.uniform(-3000, 3000), rng.uniform(-3000, 3000), rng.uniform(-3000, 3000))
        cmds = [int(v) for v in h.ask("forces %.17g %.17g %.17g %.17g %.17g %.17g" % (*p, *f)).split()]
        forces.append({"p": list(p), "force": list(f), "commands": cmds})
    rng = random.Random(4)
    theta = []
    for _ in range(100):
        n = rng.randrange(-3000, 3000)
        theta.append({"count": n, "degrees": float(h.ask(f"theta {n}"))})
    fk = []
    for p in points(60, 5):
        enc = [K.encoder_from_theta(t) for t in K.ik(p)[0]]
        answers = [floats(h.ask("pos %d %d %d" % tuple(enc))) for _ in range(3)]
        fk.append({"p": list(p), "encoders": enc, "answers": answers})
    return {"ik": ik, "forces": forces, "theta": theta, "fk": fk}


def packets(h: Harness) -> dict:
    rng = random.Random(6)
    pack, unpack = [], []
    for _ in range(300):
        cmds = [rng.randrange(-4096, 4097) for _ in range(3)]
        leds = rng.choice((0, P.LED_RED, P.LED_GREEN, P.LED_BLUE, P.LED_RED | P.LED_BLUE))
        homing = rng.random() < 0.5
        pack.append({"commands": cmds, "leds": leds, "homing": homing,
                     "packet": h.ask(f"pack {cmds[0]} {cmds[1]} {cmds[2]} {leds} {int(homing)}")})
        enc = [rng.randrange(-32768, 32768) for _ in range(3)]
        homed, buttons = rng.randrange(8), rng.randrange(16)
        packet = P.encode_status(enc, homed, buttons).hex()
        e0, e1, e2, hs, grip, ok = (int(v) for v in h.ask(f"unpack {packet}").split())
        unpack.append({"packet": packet, "encoders": [e0, e1, e2], "homing_status": hs, "grip": grip,
                       "ok": bool(ok)})
    return {"pack": pack, "unpack": unpack}


def load(h: Harness, image: bytes, corrupt_at: int | None) -> dict:
    """libnifalcon's loader on ``image``; each echo is the block, or with byte ``corrupt_at`` of the image flipped."""
    h.send(f"load {len(image)}\n{image.hex()}\n")
    blocks, off = [], 0
    while True:
        line = h.line()
        if line.startswith("LOAD"):
            break
        if not line.startswith("W "):
            raise SystemExit(f"error: unexpected harness line during load: {line!r}")
        block = bytearray.fromhex(line[2:])
        blocks.append(block.hex())
        echo = bytearray(block)
        if corrupt_at is not None and off <= corrupt_at < off + len(block):
            echo[corrupt_at - off] ^= 0x5A
        off += len(block)
        h.send(f"R {echo.hex()}\n")
    _, ok, code = line.split()
    return {"image": image.hex(), "corrupt_echo_at": corrupt_at, "blocks": blocks, "ok": ok == "1",
            "error_code": int(code)}


def sha256(rel: str) -> str:
    return hashlib.sha256((HERE / rel).read_bytes()).hexdigest()


def dump(data: dict) -> str:
    """JSON with one record a line (reviewable diffs when libnifalcon or the harness changes)."""
    lines = ["{"]
    for i, (key, value) in enumerate(data.items()):
        sep = "," if i < len(data) - 1 else ""
        if isinstance(value, list):
            rows = [json.dumps(v, separators=(",", ":")) for v in value]
            lines.append(f" {json.dumps(key)}: [\n  " + ",\n  ".join(rows) + f"\n ]{sep}")
        else:
            lines.append(f" {json.dumps(key)}: {json.dumps(value, separators=(',', ':'))}{sep}")
    return "\n".join(lines) + "\n}\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--harness", required=True, type=Path,
                    help="the falcon_harness executable, linked against libnifalcon (outside this repository)")
    ap.add_argument("--libnifalcon-commit", required=True,
                    help="the libnifalcon commit the harness was linked with (40 hex digits), recorded in the file")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"the vector file (default {DEFAULT_OUT})")
    a = ap.parse_args(argv)
    if not re.fullmatch(r"[0-9a-f]{40}", a.libnifalcon_commit):
        ap.error(f"--libnifalcon-commit: {a.libnifalcon_commit!r} is not a 40-digit commit id")
    if not a.harness.is_file():
        ap.error(f"--harness: {a.harness} is not a file")
    h = Harness(a.harness)
    try:
        data = {
            "source": {"project": "libnifalcon", "url": "https://github.com/libnifalcon/libnifalcon",
                       "commit": a.libnifalcon_commit, "licence": "BSD-3-Clause",
                       "copyright": "Copyright (c) 2007-2016, The libnifalcon Project",
                       "functions": ["FalconKinematicStamper::IK", "FalconKinematicStamper::jacobian",
                                     "FalconKinematicStamper::getForces", "FalconKinematic::getTheta",
                                     "FalconKinematicStamper::getPosition", "FalconFirmwareNovintSDK::runIOLoop",
                                     "FalconFirmware::loadFirmware"]},
            "harness_sha256": {rel: sha256(rel) for rel in HARNESS_SOURCES},
            **kinematics(h),
            **packets(h),
            "loader": [load(h, stand_in_firmware(1000, seed=9), None),
                       load(h, stand_in_firmware(700, seed=3), 2 * P.UPLOAD_BLOCK + 17)],
        }
    finally:
        h.close()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(dump(data))
    print(f"wrote {a.out} ({a.out.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
