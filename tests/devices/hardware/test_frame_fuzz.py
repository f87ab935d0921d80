"""Fuzz tests of the host's frame parser and of the serial driver's reader (issue 38), seeded and bounded.

The parser gets streams of valid frames, random garbage (sync patterns included), bit-flipped and truncated
frames in random chunks. The driver talks to a device on a real pseudo-terminal that answers every command
with a seeded mix of a good STATE, malformed CRC-valid frames (wrong size, wrong direction), random frames of
every type, corrupted and truncated frames, garbage and silence: every ``read()`` must return a state the
device really sent (or hold the last one), never raise anything but DeviceError, never a NaN."""

import math
import os
import random
import threading
import tty

from devices import DeviceError
from devices.base import DeviceInfo
from devices.hardware import wire_protocol as P
from devices.hardware.serial_device import SerialDevice

DEVICE_TYPES = [P.INFO, P.STATE, P.EVENT, P.ACK, P.NAK, P.PONG]


def _random_frame(rng: random.Random) -> bytes:
    t = rng.choice(list(P.TYPE_NAMES))
    return P.encode_frame(t, rng.randrange(256), bytes(rng.randrange(256) for _ in range(rng.randrange(0, 40))))


def test_frame_parser_fuzz():
    """3 seeds x 400 segments: every valid frame is found, in order, whatever surrounds it and however the bytes
    are chunked; nothing else is, and the counters add up."""
    for seed in (1, 2, 3):
        rng = random.Random(seed)
        stream, sent, corrupted = bytearray(), [], 0
        for _ in range(400):
            kind = rng.random()
            if kind < 0.5:
                f = P.Frame(rng.choice(DEVICE_TYPES), rng.randrange(256),
                            bytes(rng.randrange(256) for _ in range(rng.randrange(0, 60))))
                sent.append(f)
                stream += P.encode_frame(f.type, f.seq, f.payload)
            elif kind < 0.7:  # garbage, sometimes with sync patterns and plausible headers inside
                junk = bytearray(rng.randrange(256) for _ in range(rng.randrange(1, 30)))
                if rng.random() < 0.5:
                    at = rng.randrange(len(junk))
                    junk[at:at] = P.SYNC + bytes((rng.randrange(256), rng.choice(DEVICE_TYPES)))
                stream += junk
            elif kind < 0.85:  # one bit flipped (CRC-16 detects every single-bit error)
                frame = bytearray(_random_frame(rng))
                frame[rng.randrange(2, len(frame))] ^= 1 << rng.randrange(8)
                stream += frame
                corrupted += 1
            else:  # cut short: the next frame starts inside it
                frame = _random_frame(rng)
                stream += frame[:rng.randrange(1, len(frame))]
        parser, found, pos = P.FrameParser(), [], 0
        while pos < len(stream):
            n = rng.choice([1, 2, 7, 64, 500])
            found += parser.feed(bytes(stream[pos:pos + n]))
            pos += n
        for _ in range(len(stream)):  # what a driver does when a reply is overdue: give up a pending partial frame
            if parser.pending_bytes < P.HEADER_SIZE:
                break
            found += parser.skip_partial()
        assert found == sent, (seed, len(found), len(sent))
        assert parser.frames_ok == len(sent) and parser.crc_errors >= corrupted


class FuzzDevice:
    """A device on the master side of a pty: answers the handshake honestly, then every CURRENT with fuzz."""

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.parser = P.FrameParser()
        self.seq = 0
        self.t_us = 1000
        self.good = {}           # t_us of every good STATE sent -> its encoder count
        self.injected = {"malformed": 0, "silent": 0}
        self.stop = threading.Event()
        info = DeviceInfo(name="fuzz", encoder_lines=500, gear_ratio=10.0, handle_length_m=0.1,
                          torque_constant_Nm_A=0.02, current_continuous_A=1.0, current_peak_A=2.0,
                          current_amplifier_A=2.0, servo_rate_hz=1000.0)
        self.info = P.encode_info(P.WireInfo(info, P.PROTOCOL_VERSION, (1, 0, 0), "F1", 0.01, 0, 0.01, 0, 100,
                                             P.CAP_STREAMING, 0))
        self.thread = threading.Thread(target=self.serve, daemon=True)
        self.thread.start()

    def frame(self, t: int, payload: bytes) -> bytes:
        self.seq = (self.seq + 1) & 0xFF
        return P.encode_frame(t, self.seq, payload)

    def good_state(self, cmd_seq: int) -> bytes:
        self.t_us += 1000
        enc = self.rng.randrange(-5000, 5000)
        self.good[self.t_us] = enc
        return self.frame(P.STATE, P.encode_state(self.t_us, enc, 10, 200, 0, cmd_seq, 0))

    def answer(self, cmd_seq: int) -> bytes:
        rng = self.rng
        out = bytearray()
        for _ in range(rng.choice([0, 0, 1, 1, 2, 3])):  # some junk before the reply
            kind = rng.randrange(7)
            if kind == 0:    # a STATE of the wrong size, CRC valid, plausible values: must never be applied
                n = rng.choice([0, 1, 15, 17, 20, 40])
                out += self.frame(P.STATE, bytes(rng.randrange(256) for _ in range(n)))
                self.injected["malformed"] += 1
            elif kind == 1:  # a host -> device type from the device
                out += self.frame(rng.choice([P.CURRENT, P.SET_MODE, P.WALL, P.KEEPALIVE]),
                                  bytes(rng.randrange(256) for _ in range(rng.randrange(0, 30))))
                self.injected["malformed"] += 1
            elif kind == 2:  # an EVENT with a NaN or inf in it
                out += self.frame(P.EVENT, P.EVENT_STRUCT.pack(self.t_us, rng.choice([math.nan, math.inf]), 1.0,
                                                                0.001, 5.0, 0, 0, 0))
                self.injected["malformed"] += 1
            elif kind == 3:  # well-formed frames the host did not ask for: an ACK, a NAK, a PONG of random content
                t = rng.choice([P.NAK, P.PONG, P.ACK])
                n = 2 if t == P.ACK else rng.randrange(3 if t == P.NAK else 0, 50)
                out += self.frame(t, bytes(rng.randrange(256) for _ in range(n)))
            elif kind == 4:  # garbage with a sync pattern in it
                out += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 20))) + P.SYNC
            elif kind == 5:  # a corrupted frame
                f = bytearray(self.frame(P.STATE, bytes(16)))
                f[rng.randrange(2, len(f))] ^= 1 << rng.randrange(8)
                out += f
            else:            # a frame cut short
                f = self.frame(P.PONG, bytes(rng.randrange(256) for _ in range(20)))
                out += f[:rng.randrange(1, len(f))]
        if rng.random() < 0.03:
            self.injected["silent"] += 1
            return bytes(out)
        return bytes(out) + self.good_state(cmd_seq)

    def serve(self) -> None:
        import select

        while not self.stop.is_set():
            ready, _, _ = select.select((self.master,), (), (), 0.05)
            if not ready:
                continue
            try:
                data = os.read(self.master, 4096)
            except OSError:
                return
            for f in self.parser.feed(data):
                if f.type == P.HELLO:
                    reply = self.frame(P.INFO, self.info)
                elif f.type == P.CURRENT:
                    reply = self.answer(f.seq)
                else:
                    reply = self.frame(P.ACK, bytes((f.type, f.seq)))
                os.write(self.master, reply)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        os.close(self.master)
        os.close(self.slave)


def test_serial_driver_reader_fuzz():
    """2000 commands against the fuzzing device (seeded; about 2 s). A late reply on a loaded machine is a
    counted loss like a silent one: the loss budget is opened wide so only the frames decide."""
    dev_side = FuzzDevice(seed=38)
    try:
        dev = SerialDevice(dev_side.port, loss_timeout_s=0.05, max_consecutive_losses=100, max_loss_rate=1.0)
        dev.open()
        res = dev.info.position_resolution_m
        held = 0
        for _ in range(2000):
            try:
                st = dev.read()
            except DeviceError as exc:  # the only exception allowed; with this budget it must not come
                raise AssertionError(f"link declared dead: {exc}") from None
            assert not st.status & 32, st.extra.get("error")
            for v in (st.t_s, st.position_m, st.accel_m_s2, st.grip_N):
                assert math.isfinite(v)
            if st.extra.get("held"):
                held += 1
            elif st.t_s:  # every state returned is one the device sent as good, decoded exactly
                t_us = round(st.t_s * 1e6)
                assert t_us in dev_side.good, t_us
                assert st.position_m == dev_side.good[t_us] * res
            dev.command(0.0)
        dev.read()  # the answer to the last command: every frame the device sent has been through the reader
        stats, injected = dev.link_stats(), dict(dev_side.injected)  # before close() commands a last zero
        dev.close()
    finally:
        dev_side.close()
    # every malformed frame the device sent was dropped and counted (the count is exact: none can hide in a
    # corrupted one's bytes, the parser finds every valid frame)
    assert stats["malformed_frames"] == injected["malformed"] > 100, (stats, injected)
    assert stats["losses"] >= injected["silent"] > 10
    assert held == stats["losses"] and stats["crc_errors"] > 100
    assert dev.pop_events() == []  # the NaN events never became events
