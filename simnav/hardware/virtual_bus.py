"""A virtual Dynamixel bus: X-series servo emulators behind a pseudo-terminal, so the real SDK talks to them over a
real serial port.

A daemon thread waits on the pty master, parses Protocol 2.0 instruction packets (resynchronising after garbage,
answering CRC errors), dispatches them to the servos (ping, read, write, reg write/action, reboot, factory reset,
clear, sync read/write, bulk read/write), runs each servo's motor and bus watchdog, and writes status packets after
each servo's Return Delay Time. Faults can be injected into the replies (corrupted CRC, dropped bytes, delayed or
missing replies, any byte-level filter) and the port can vanish and come back.

:class:`VirtualBus` runs the emulator in a process of its own; :class:`BusEmulator` is the same in a thread.

Example::

    with VirtualBus(ids=(1, 2)) as bus:
        port = bus.port                    # e.g. /dev/pts/7: give it to PortHandler / simnav mission --hardware
        bus.inject(ReplyFault.NO_REPLY)    # the next status packet is never sent
"""

from __future__ import annotations

import errno
import logging
import os
import pty
import random
import select
import socket
import subprocess
import sys
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from enum import StrEnum
from multiprocessing.connection import Connection
from pathlib import Path

from simnav.hardware import control_table as ct
from simnav.hardware.protocol import (
    BROADCAST_ID,
    CrcMismatch,
    ErrorCode,
    Instruction,
    Packet,
    PacketParser,
    from_le,
    status_packet,
)
from simnav.hardware.servo import EmulatedServo

log = logging.getLogger(__name__)

TICK_S = 0.002
"""The emulator thread wakes at least this often to run the motors and the watchdogs, s."""
PARTIAL_PACKET_TIMEOUT_S = 0.05
"""An incomplete packet older than this is dropped (the servo's receive timeout), s."""


class ReplyFault(StrEnum):
    """Faults injected into the next status packets."""

    CORRUPT_CRC = "corrupt_crc"
    DROP_BYTES = "drop_bytes"
    DELAY = "delay"
    NO_REPLY = "no_reply"


@dataclass
class _Injection:
    fault: ReplyFault
    count: int
    delay_s: float = 0.0
    n_bytes: int = 3


@dataclass(frozen=True)
class BusEvent:
    """Something the bus did, stamped on ``time.monotonic()``: ``kind`` is ``'fault'``, ``'goal'`` (a servo's goal
    velocity changed, by a packet or the watchdog; ``detail`` = (id, raw value)), ``'watchdog'`` (a bus watchdog
    tripped; ``detail`` = (id,)), ``'vanished'`` or ``'reappeared'``."""

    t_wall_s: float
    kind: str
    detail: tuple = field(default_factory=tuple)


class BusEmulator:
    """Emulated X-series servos on a pty, served by a thread of this process (see :class:`VirtualBus` for the
    same in a process of its own).

    Args:
        ids: servo IDs on the bus.
        model: servo model (a key of :data:`simnav.hardware.control_table.MODELS`).
        time_scale: the servos' clock runs this many times faster than the wall clock (motor response, watchdog),
            for simulations faster than real time; 1 is real time.
        motor_time_constant_s: first-order velocity response, s (servo time).
        return_delay_us: Return Delay Time of every servo, microseconds (None: the model's default, 500 us).
        link: optional stable path (a symlink to the current pty) that survives :meth:`vanish`/:meth:`reappear`.
        log_size: instruction packets and events kept for inspection.
    """

    def __init__(self, ids: Iterable[int] = (1, 2), model: str = "XL430-W250", *, time_scale: float = 1.0,
                 motor_time_constant_s: float = 0.04, return_delay_us: int | None = None,
                 link: str | Path | None = None, log_size: int = 20000) -> None:
        if time_scale <= 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale}")
        self.time_scale = time_scale
        self.link = Path(link) if link is not None else None
        self.lock = threading.RLock()
        self._wall0 = time.monotonic()
        self._setup = (tuple(ids), model, motor_time_constant_s, return_delay_us)
        self.servos = self._power_on()
        self.packets: deque[tuple[float, Packet]] = deque(maxlen=log_size)
        self.events: deque[BusEvent] = deque(maxlen=log_size)
        self.crc_errors = 0
        self._parser = PacketParser()
        self._outbox: list[tuple[float, bytes]] = []
        self._injections: deque[_Injection] = deque()
        self._reply_filter: Callable[[bytes], bytes | None] | None = None
        self._fds: tuple[int, int] | None = None
        self._port_name = ""
        self._last_rx_wall = 0.0
        self._reset_wall = 0.0
        self._requests: deque[tuple[str, threading.Event]] = deque()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _power_on(self) -> list[EmulatedServo]:
        ids, model, tau_s, return_delay_us = self._setup
        servos = [EmulatedServo(i, model, tau_s, self.now_s()) for i in ids]
        if return_delay_us is not None:
            for servo in servos:
                servo.set(ct.ADDR_RETURN_DELAY, round(return_delay_us / 2))
        return servos

    # ------------------------------------------------------------------------------------------- lifecycle
    def start(self) -> BusEmulator:
        """Open the pty and start serving; returns self."""
        self._open_pty()
        self._thread = threading.Thread(target=self._serve, name="virtual-dynamixel-bus", daemon=True)
        self._thread.start()
        log.info("virtual Dynamixel bus on %s (ids %s)", self.port, self.ids)
        return self

    def reset(self) -> None:
        """Servos back to their factory state (a power cycle), logs and injected faults cleared."""
        with self.lock:
            self._reset_wall = time.monotonic()
            self._drain()
            self.servos = self._power_on()
            self.packets.clear()
            self.events.clear()
            self._injections.clear()
            self._reply_filter = None
            self._outbox.clear()
            self._parser.reset()
            self.crc_errors = 0

    def _drain(self) -> None:
        """Discard bytes not read yet (sent before a reset)."""
        if self._fds is None:
            return
        try:
            while os.read(self._fds[0], 4096):
                pass
        except OSError:
            pass

    def stop(self) -> None:
        """Stop serving and close the pty."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._close_pty()

    def __enter__(self) -> BusEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def port(self) -> str:
        """The serial port to open: the stable link when one was given, else the pty's slave device."""
        return str(self.link) if self.link is not None else self._port_name

    @property
    def pty_name(self) -> str:
        """The current pty slave device (changes after :meth:`reappear`)."""
        return self._port_name

    @property
    def ids(self) -> list[int]:
        return [s.dxl_id for s in self.servos]

    def now_s(self) -> float:
        """The servos' clock, s (wall time since start times ``time_scale``)."""
        return (time.monotonic() - self._wall0) * self.time_scale

    # ------------------------------------------------------------------------------------------ inspection
    def servo(self, dxl_id: int) -> EmulatedServo:
        """The servo with this ID (hold :attr:`lock` while touching it from another thread)."""
        for s in self.servos:
            if s.dxl_id == dxl_id:
                return s
        raise KeyError(f"no servo with id {dxl_id} on the virtual bus (ids {self.ids})")

    def register(self, dxl_id: int, address: int) -> int:
        """Current value of a control-table item (decoded), read under the lock."""
        with self.lock:
            return self.servo(dxl_id).get(address)

    def set_register(self, dxl_id: int, address: int, value: int) -> None:
        """Store a value without access checks (test set-up)."""
        with self.lock:
            self.servo(dxl_id).set(address, value)

    def table(self, dxl_id: int) -> bytes:
        """A copy of a servo's whole control table (raw bytes)."""
        with self.lock:
            return bytes(self.servo(dxl_id).mem)

    def set_position(self, dxl_id: int, ticks: int) -> None:
        """Place a servo's multi-turn Present Position (test set-up, e.g. near the int32 wrap-around)."""
        with self.lock:
            self.servo(dxl_id).set_position(ticks)

    def instructions(self, since_s: float = 0.0) -> list[Packet]:
        """Instruction packets received after ``since_s`` (``time.monotonic()``), oldest first."""
        with self.lock:
            return [p for t, p in self.packets if t >= since_s]

    def timed_instructions(self, since_s: float = 0.0) -> list[tuple[float, Packet]]:
        """``(time.monotonic() stamp, packet)`` of the instruction packets received after ``since_s``."""
        with self.lock:
            return [(t, p) for t, p in self.packets if t >= since_s]

    def bus_events(self, since_s: float = 0.0) -> list[BusEvent]:
        """Events (faults applied, goal velocity changes, port vanished/back) after ``since_s``."""
        with self.lock:
            return [e for e in self.events if e.t_wall_s >= since_s]

    def get_crc_errors(self) -> int:
        """Instruction packets received with a wrong CRC so far."""
        return self.crc_errors

    # --------------------------------------------------------------------------------------------- faults
    def inject(self, fault: ReplyFault | str, count: int = 1, *, delay_s: float = 0.1, n_bytes: int = 3) -> None:
        """Apply ``fault`` to the next ``count`` status packets (delay ``delay_s``; drop ``n_bytes``)."""
        with self.lock:
            self._injections.append(_Injection(ReplyFault(fault), count, delay_s, n_bytes))

    def set_reply_filter(self, fn: Callable[[bytes], bytes | None] | None) -> None:
        """Pass every status packet through ``fn`` (None: drop it) -- arbitrary corruption for fuzzing."""
        with self.lock:
            self._reply_filter = fn

    def raise_hardware_error(self, dxl_id: int, bits: int = 0x20) -> None:
        """Set Hardware Error Status bits (default overload) on one servo."""
        with self.lock:
            self.servo(dxl_id).raise_hardware_error(bits)
            self.events.append(BusEvent(time.monotonic(), "fault", ("hardware_error", dxl_id, bits)))

    def vanish(self) -> None:
        """Unplug: close the pty (and remove the link); the servos keep running on their own."""
        self._request("vanish")

    def reappear(self) -> None:
        """Plug back in: a new pty (the link, if any, points at it)."""
        self._request("reappear")

    def _request(self, what: str) -> None:
        if self._thread is None or not self._thread.is_alive():
            with self.lock:
                self._handle_request(what)
            return
        done = threading.Event()
        self._requests.append((what, done))
        done.wait(timeout=2.0)

    # ----------------------------------------------------------------------------------------------- pty
    def _open_pty(self) -> None:
        master, slave = pty.openpty()
        tty.setraw(slave)  # no echo, no CR/LF translation
        os.set_blocking(master, False)
        self._fds = (master, slave)
        self._port_name = os.ttyname(slave)
        self._parser.reset()
        self._outbox.clear()
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".tmp")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(self._port_name)
            tmp.replace(self.link)

    def _close_pty(self) -> None:
        if self._fds is not None:
            for fd in self._fds:
                try:
                    os.close(fd)
                except OSError:
                    pass
            self._fds = None
        if self.link is not None and self.link.is_symlink():
            self.link.unlink(missing_ok=True)

    def _handle_request(self, what: str) -> None:
        if what == "vanish":
            self._close_pty()
            self.events.append(BusEvent(time.monotonic(), "vanished"))
        elif what == "reappear" and self._fds is None:
            self._open_pty()
            self.events.append(BusEvent(time.monotonic(), "reappeared", (self._port_name,)))

    # ---------------------------------------------------------------------------------------------- serve
    def _serve(self) -> None:
        while not self._stop.is_set():
            while self._requests:
                what, done = self._requests.popleft()
                with self.lock:
                    self._handle_request(what)
                done.set()
            data = self._receive(self._wait_s())
            read_at = time.monotonic()
            with self.lock:
                self._step(data if read_at > self._reset_wall else b"")

    def _wait_s(self) -> float:
        if not self._outbox:
            return TICK_S
        return min(TICK_S, max(0.0, min(due for due, _ in self._outbox) - time.monotonic()))

    def _receive(self, timeout_s: float) -> bytes:
        """Bytes from the pty within ``timeout_s`` (none when unplugged)."""
        if self._fds is None:
            time.sleep(timeout_s)
            return b""
        master = self._fds[0]
        try:
            ready, _, _ = select.select([master], [], [], timeout_s)
            return os.read(master, 4096) if ready else b""
        except (OSError, ValueError):
            return b""

    def _step(self, data: bytes) -> None:
        wall = time.monotonic()
        # Parse: complete packets in order; an incomplete one that stays incomplete is dropped
        if data:
            self._last_rx_wall = wall
            items = self._parser.feed(data)
        else:
            items = []
            while self._parser.pending and wall - self._last_rx_wall > PARTIAL_PACKET_TIMEOUT_S:
                self._parser.drop_partial()
                items += self._parser.feed(b"")
        # Motors up to now, then the packets (they count for the watchdog even if this process was late to look)
        now = self.now_s()
        for servo in self.servos:
            servo.advance(now)
        for item in items:
            self._dispatch(item, wall, now)
        for servo in self.servos:
            goal = servo.get(ct.ADDR_GOAL_VELOCITY)
            if servo.check_watchdog(now):
                self.events.append(BusEvent(wall, "watchdog", (servo.dxl_id,)))
                if goal:
                    self.events.append(BusEvent(wall, "goal", (servo.dxl_id, 0)))
        # Replies whose time has come
        self._flush(wall)

    def _flush(self, wall: float) -> None:
        due = [msg for t, msg in self._outbox if t <= wall]
        self._outbox = [(t, msg) for t, msg in self._outbox if t > wall]
        for msg in due:
            self._write(msg)

    def _write(self, data: bytes) -> None:
        if self._fds is None:
            return
        try:
            os.write(self._fds[0], data)
        except OSError as err:  # nobody reading and the buffer full, or unplugged: bytes lost, as on a wire
            if err.errno not in (errno.EAGAIN, errno.EIO, errno.EBADF):
                log.warning("virtual bus write failed: %s", err)

    # ------------------------------------------------------------------------------------------- dispatch
    def _dispatch(self, item: Packet | CrcMismatch, wall: float, now: float) -> None:
        if isinstance(item, CrcMismatch):
            self.crc_errors += 1
            servo = self._find(item.dxl_id)
            if servo is not None and servo.mem[ct.ADDR_STATUS_RETURN_LEVEL] == 2:
                self._reply([(servo, servo.error_byte(ErrorCode.CRC), b"")], wall)
            return
        self.packets.append((wall, item))
        goals_before = {s.dxl_id: s.get(ct.ADDR_GOAL_VELOCITY) for s in self.servos}
        for servo in self.servos:
            if item.dxl_id in (servo.dxl_id, BROADCAST_ID):
                servo.heard(now)
        if item.dxl_id == BROADCAST_ID:
            self._broadcast(item, wall)
        else:
            servo = self._find(item.dxl_id)
            if servo is not None:
                self._unicast(servo, item, wall)
        for servo in self.servos:
            before = goals_before.get(servo.dxl_id)
            value = servo.get(ct.ADDR_GOAL_VELOCITY)
            if before is None or value != before:
                self.events.append(BusEvent(wall, "goal", (servo.dxl_id, value)))

    def _find(self, dxl_id: int) -> EmulatedServo | None:
        return next((s for s in self.servos if s.dxl_id == dxl_id), None)

    def _unicast(self, servo: EmulatedServo, pkt: Packet, wall: float) -> None:
        inst, p = pkt.instruction, pkt.params
        if inst == Instruction.PING:
            model = servo.get(ct.ADDR_MODEL_NUMBER)
            self._reply([(servo, servo.error_byte(0), bytes([model & 0xFF, model >> 8, servo.mem[6]]))], wall,
                        kind="ping")
            return
        if inst == Instruction.READ:
            if len(p) != 4:
                self._reply([(servo, servo.error_byte(ErrorCode.DATA_LENGTH), b"")], wall, kind="read")
                return
            error, data = servo.read(from_le(p[0:2]), from_le(p[2:4]))
            self._reply([(servo, servo.error_byte(error), data)], wall, kind="read")
            return
        alert = servo.error_byte(0)  # REBOOT and FACTORY_RESET answer with the state before they act
        error = self._execute(servo, inst, p)
        before = inst in (Instruction.REBOOT, Instruction.FACTORY_RESET)
        self._reply([(servo, alert | error if before else servo.error_byte(error), b"")], wall)

    def _execute(self, servo: EmulatedServo, inst: int, p: bytes) -> int:
        """Instructions answered by an empty status packet; returns the error code."""
        if inst in (Instruction.WRITE, Instruction.REG_WRITE):
            if len(p) < 3:
                return ErrorCode.DATA_LENGTH
            op = servo.write if inst == Instruction.WRITE else servo.reg_write
            return op(from_le(p[0:2]), p[2:])
        if inst == Instruction.ACTION:
            return servo.action()
        if inst == Instruction.REBOOT:
            servo.reboot()
            return ErrorCode.NONE
        if inst == Instruction.FACTORY_RESET:
            return servo.factory_reset(p[0]) if len(p) == 1 else ErrorCode.DATA_LENGTH
        if inst == Instruction.CLEAR:
            return servo.clear_multi_turn(p)
        return ErrorCode.INSTRUCTION

    def _broadcast(self, pkt: Packet, wall: float) -> None:
        inst, p = pkt.instruction, pkt.params
        if inst == Instruction.PING:
            replies = [(s, s.error_byte(0), bytes([s.mem[0], s.mem[1], s.mem[6]]))
                       for s in sorted(self.servos, key=lambda s: s.dxl_id)]
            self._reply(replies, wall, kind="ping")
        elif inst == Instruction.SYNC_READ and len(p) >= 5:
            address, length = from_le(p[0:2]), from_le(p[2:4])
            listed = [s for s in (self._find(i) for i in p[4:]) if s is not None]
            self._reply([(s, s.error_byte(err), data) for s in listed
                         for err, data in [s.read(address, length)]], wall, kind="read")
        elif inst == Instruction.SYNC_WRITE and len(p) >= 5:
            self._sync_write(p)
        elif inst == Instruction.BULK_READ and len(p) >= 5 and len(p) % 5 == 0:
            entries = [(self._find(p[k]), from_le(p[k + 1:k + 3]), from_le(p[k + 3:k + 5]))
                       for k in range(0, len(p), 5)]
            self._reply([(s, s.error_byte(err), data) for s, a, n in entries if s is not None
                         for err, data in [s.read(a, n)]], wall, kind="read")
        elif inst == Instruction.BULK_WRITE:
            self._bulk_write(p)
        elif inst in (Instruction.WRITE, Instruction.REG_WRITE, Instruction.ACTION, Instruction.REBOOT,
                      Instruction.CLEAR):
            for servo in self.servos:
                self._execute(servo, inst, p)

    def _sync_write(self, p: bytes) -> None:
        address, length = from_le(p[0:2]), from_le(p[2:4])
        block = 1 + length
        if length == 0 or (len(p) - 4) % block:
            return  # malformed: ignored, and a broadcast gets no status
        for k in range(4, len(p), block):
            servo = self._find(p[k])
            if servo is not None:
                servo.write(address, p[k + 1:k + block])

    def _bulk_write(self, p: bytes) -> None:
        k = 0
        while k + 5 <= len(p):
            servo, address, length = self._find(p[k]), from_le(p[k + 1:k + 3]), from_le(p[k + 3:k + 5])
            data = p[k + 5:k + 5 + length]
            if len(data) < length or length == 0:
                return
            if servo is not None:
                servo.write(address, data)
            k += 5 + length

    # -------------------------------------------------------------------------------------------- replies
    def _reply(self, replies: list[tuple[EmulatedServo, int, bytes]], wall: float, kind: str = "write") -> None:
        """Queue status packets, each after the previous one plus its servo's Return Delay Time, unless the
        Status Return Level keeps the servo silent (0: ping only; 1: ping and reads; 2: all)."""
        due = wall
        for servo, error, params in replies:
            level = servo.mem[ct.ADDR_STATUS_RETURN_LEVEL]
            if kind != "ping" and (level == 0 or (level == 1 and kind != "read")):
                continue
            due += servo.mem[ct.ADDR_RETURN_DELAY] * ct.RETURN_DELAY_UNIT_S
            msg, delay = self._faulted(status_packet(servo.dxl_id, error, params), wall)
            due += delay  # the next servo answers after this one (half duplex)
            if msg is not None:
                self._outbox.append((due, msg))
        self._flush(time.monotonic())

    def _faulted(self, msg: bytes, wall: float) -> tuple[bytes | None, float]:
        """Apply the next injected fault (or the reply filter) to one status packet: (bytes or None, delay s)."""
        if self._reply_filter is not None:
            return self._reply_filter(msg), 0.0
        if not self._injections:
            return msg, 0.0
        inj = self._injections[0]
        inj.count -= 1
        if inj.count <= 0:
            self._injections.popleft()
        self.events.append(BusEvent(wall, "fault", (inj.fault.value,)))
        if inj.fault is ReplyFault.NO_REPLY:
            return None, 0.0
        if inj.fault is ReplyFault.CORRUPT_CRC:
            return msg[:-1] + bytes([msg[-1] ^ 0xFF]), 0.0
        if inj.fault is ReplyFault.DROP_BYTES:
            cut = min(inj.n_bytes, len(msg) - 8)
            return msg[:8] + msg[8 + cut:], 0.0
        return msg, inj.delay_s


class RandomCorruption:
    """A reply filter (see :meth:`BusEmulator.set_reply_filter`) that corrupts a fraction of the status packets at
    random: flipped bits, dropped, duplicated or inserted bytes, truncation, garbage before the header, or no reply.

    Args:
        probability: share of the status packets corrupted.
        seed: seed of the corruption stream.
    """

    def __init__(self, probability: float = 0.5, seed: int = 0) -> None:
        self.probability = probability
        self.seed = seed
        self._rng: random.Random | None = None

    def __call__(self, msg: bytes) -> bytes | None:
        rng = self._rng = self._rng or random.Random(self.seed)
        if rng.random() >= self.probability:
            return msg
        data = bytearray(msg)
        kind = rng.randrange(7)
        if kind == 0:  # flipped bits
            for _ in range(rng.randint(1, 4)):
                data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        elif kind == 1:  # a byte lost
            del data[rng.randrange(len(data))]
        elif kind == 2:  # a byte repeated
            k = rng.randrange(len(data))
            data.insert(k, data[k])
        elif kind == 3:  # truncated
            data = data[:rng.randrange(len(data))]
        elif kind == 4:  # garbage before the header
            data = bytearray(rng.randbytes(rng.randint(1, 12))) + data
        elif kind == 5:  # random bytes in place of the reply
            data = bytearray(rng.randbytes(rng.randint(1, 40)))
        else:
            return None
        return bytes(data)


class VirtualBus:
    """A :class:`BusEmulator` in a process of its own (the SDK busy-polls the port, so an emulator thread in the same
    process would wait for the interpreter lock), driven through a pipe. Same arguments and methods as
    :class:`BusEmulator`; reply filters must be picklable (e.g. :class:`RandomCorruption`).

    Example::

        with VirtualBus(ids=(1, 2)) as bus:
            print(bus.port)                     # /dev/pts/N
            bus.inject(ReplyFault.CORRUPT_CRC)
    """

    def __init__(self, ids: Iterable[int] = (1, 2), model: str = "XL430-W250", **kwargs) -> None:
        self._kwargs = dict(ids=tuple(ids), model=model, **kwargs)
        self.time_scale = float(kwargs.get("time_scale", 1.0))
        self._conn: Connection | None = None
        self._proc: subprocess.Popen | None = None
        self._call_lock = threading.Lock()
        self.link = kwargs.get("link")

    def start(self) -> VirtualBus:
        """Start the emulator process and wait until its pty is open."""
        parent, child = socket.socketpair()
        code = "import sys; from simnav.hardware.virtual_bus import _serve_fd; _serve_fd(int(sys.argv[1]))"
        env = dict(os.environ)
        root = str(Path(__file__).resolve().parents[2])
        env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
        # A session of its own: Ctrl-C reaches the bridge (which stops the motors through this bus), not the bus
        self._proc = subprocess.Popen([sys.executable, "-c", code, str(child.fileno())], pass_fds=[child.fileno()],
                                      stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, env=env,
                                      start_new_session=True)
        child.close()
        self._conn = Connection(parent.detach())
        self._conn.send(self._kwargs)
        if not self._conn.poll(RPC_START_TIMEOUT_S):
            self.stop()
            raise RuntimeError("the virtual Dynamixel bus process did not start")
        status, value = self._conn.recv()
        if status != "ok":
            self.stop()
            raise RuntimeError(f"the virtual Dynamixel bus failed to start: {value}")
        return self

    def stop(self) -> None:
        """Stop the emulator process (the pty goes with it)."""
        if self._conn is not None:
            try:
                self._conn.send(("stop", (), {}))
                self._conn.poll(RPC_TIMEOUT_S)
            except (OSError, EOFError):
                pass
            self._conn.close()
            self._conn = None
        if self._proc is not None:
            try:
                self._proc.wait(timeout=RPC_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(timeout=RPC_TIMEOUT_S)
            self._proc = None

    def __enter__(self) -> VirtualBus:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _call(self, method: str, *args, **kwargs):
        with self._call_lock:
            if self._conn is None:
                raise RuntimeError("the virtual Dynamixel bus is not running")
            self._conn.send((method, args, kwargs))
            if not self._conn.poll(RPC_TIMEOUT_S):
                raise RuntimeError(f"the virtual Dynamixel bus did not answer '{method}'")
            status, value = self._conn.recv()
        if status != "ok":
            raise RuntimeError(f"virtual bus '{method}': {value}")
        return value

    @property
    def port(self) -> str:
        """The serial port to open (the link when one was given)."""
        return str(self.link) if self.link is not None else self._call("_attr", "pty_name")

    @property
    def pty_name(self) -> str:
        return self._call("_attr", "pty_name")

    @property
    def ids(self) -> list[int]:
        return self._call("_attr", "ids")

    def now_s(self) -> float:
        return self._call("now_s")

    def reset(self) -> None:
        self._call("reset")

    def register(self, dxl_id: int, address: int) -> int:
        return self._call("register", dxl_id, address)

    def set_register(self, dxl_id: int, address: int, value: int) -> None:
        self._call("set_register", dxl_id, address, value)

    def set_position(self, dxl_id: int, ticks: int) -> None:
        self._call("set_position", dxl_id, ticks)

    def table(self, dxl_id: int) -> bytes:
        return self._call("table", dxl_id)

    def instructions(self, since_s: float = 0.0) -> list[Packet]:
        return self._call("instructions", since_s)

    def timed_instructions(self, since_s: float = 0.0) -> list[tuple[float, Packet]]:
        return self._call("timed_instructions", since_s)

    def bus_events(self, since_s: float = 0.0) -> list[BusEvent]:
        return self._call("bus_events", since_s)

    def get_crc_errors(self) -> int:
        return self._call("get_crc_errors")

    def inject(self, fault: ReplyFault | str, count: int = 1, *, delay_s: float = 0.1, n_bytes: int = 3) -> None:
        self._call("inject", ReplyFault(fault), count, delay_s=delay_s, n_bytes=n_bytes)

    def set_reply_filter(self, fn: Callable[[bytes], bytes | None] | None) -> None:
        self._call("set_reply_filter", fn)

    def raise_hardware_error(self, dxl_id: int, bits: int = 0x20) -> None:
        self._call("raise_hardware_error", dxl_id, bits)

    def vanish(self) -> None:
        self._call("vanish")

    def reappear(self) -> None:
        self._call("reappear")


RPC_START_TIMEOUT_S = 30.0
RPC_TIMEOUT_S = 5.0


def _serve_fd(fd: int) -> None:
    """Entry point of the emulator process: a connection on ``fd`` brings the arguments, then the calls."""
    conn = Connection(fd)
    try:
        kwargs = conn.recv()
    except (EOFError, OSError):
        return
    _serve(conn, kwargs)


def _serve(conn: Connection, kwargs: dict) -> None:
    """Start the bus, then answer calls until 'stop' or the parent goes away."""
    try:
        emulator = BusEmulator(**kwargs).start()
    except Exception as err:  # reported to the parent, which raises
        conn.send(("error", f"{type(err).__name__}: {err}"))
        return
    conn.send(("ok", emulator.pty_name))
    try:
        while True:
            try:
                method, args, kw = conn.recv()
            except (EOFError, OSError):
                break
            if method == "stop":
                conn.send(("ok", None))
                break
            try:
                value = getattr(emulator, args[0]) if method == "_attr" else getattr(emulator, method)(*args, **kw)
                conn.send(("ok", value))
            except Exception as err:  # any failure of one call goes back to the caller
                conn.send(("error", f"{type(err).__name__}: {err}"))
    finally:
        emulator.stop()
