"""Live Link Face's UDP stream: its packets read (and written), and :class:`LiveLink`, a socket
that gives the newest frame of the stream, dropping (never queueing) the ones a slow consumer missed.

The packet
----------
Epic's iPhone app *Live Link Face* (target "Live Link", Unreal Engine's ``AppleARKitFaceSupport``
protocol) sends one UDP datagram per camera frame to each target's IP address and port (11111 by
default). All numbers are big-endian (network order):

======  ==========================  =====================================================
bytes   field                       meaning
======  ==========================  =====================================================
1       version, uint8              6 (the only layout read here)
4 + n   device id                   int32 byte count n, then n bytes UTF-8 (the phone's id)
4 + m   subject name                int32 byte count m, then m bytes UTF-8 (the app's name)
4       frame number, int32         frames at the rate below (the app's timecode)
4       sub-frame, float32          the fraction of a frame in [0, 1)
4       rate numerator, int32       e.g. 60 ...
4       rate denominator, int32     ... and 1: 60 frames per second
1       channel count, uint8        61
4 x 61  channels, float32           the 52 ARKit weights (:data:`~facewarp.ARKIT_NAMES`
                                    order), HeadYaw, HeadPitch, HeadRoll, then the left and
                                    right eye's yaw, pitch and roll [rad]
======  ==========================  =====================================================

The channel order differs from Live Link Face's CSV only in where the time goes (the CSV has
``Timecode, BlendShapeCount`` first); both carry the 52 weights in ARKit's order, then the head,
then the eyes. A frame's time is ``(frame + sub_frame) * denominator / numerator`` seconds.

A datagram that does not parse (too short, another version, a byte count beyond the datagram, a
rate that is not positive, a channel count other than 61, a NaN or infinite value, a weight
outside [-0.1, 1.1], an angle beyond +-pi) is a :class:`PacketError`: :class:`LiveLink` counts it
by reason and skips it. Bytes after the 61st channel are ignored (room for a later layout that
appends). Weights a little outside [0, 1] (real ARKit weights reach about 1.05) are kept as sent
and clamped to [0, 1] in :attr:`LiveLinkFrame.weights`; the frames that needed it are counted.
"""

from __future__ import annotations

import errno
import math
import socket
import struct
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from .tracks import ARKIT_NAMES

__all__ = [
    "DEFAULT_PORT",
    "LIVELINK_CHANNELS",
    "PACKET_VERSION",
    "LiveLink",
    "LiveLinkFrame",
    "LiveLinkStats",
    "PacketError",
    "encode_packet",
    "parse_packet",
    "write_livelink_csv",
]

DEFAULT_PORT = 11111
"""Live Link Face's default target port."""

PACKET_VERSION = 6
"""The packet layout read here (the first byte of every datagram)."""

HEAD_CHANNELS = ("HeadYaw", "HeadPitch", "HeadRoll")
EYE_CHANNELS = ("LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw", "RightEyePitch", "RightEyeRoll")
LIVELINK_CHANNELS = tuple(n[0].upper() + n[1:] for n in ARKIT_NAMES) + HEAD_CHANNELS + EYE_CHANNELS
"""The 61 channels of a packet, in order: the 52 ARKit weights (capitalised as in the CSV), the
head's yaw, pitch and roll, the left and the right eye's yaw, pitch and roll [rad]."""

WEIGHT_RANGE = (-0.1, 1.1)
"""Weights outside this range make a packet malformed; inside it they are clamped to [0, 1]."""

MAX_STRING_BYTES = 1024
"""A device id or subject name longer than this is not Live Link Face's."""

MAX_RATE = 1000.0
"""The fastest frame rate a packet may state [1/s]."""

_HEADER_TAIL = struct.Struct(">ifiiB")  # frame number, sub-frame, rate numerator, denominator, channel count
_CHANNELS = struct.Struct(">61f")
MIN_PACKET_BYTES = 1 + 4 + 4 + _HEADER_TAIL.size + _CHANNELS.size
"""The shortest valid datagram (empty device id and subject name): 270 bytes."""


class PacketError(InputError):
    """A datagram that is not a Live Link Face packet (an :class:`~facewarp.InputError`);
    ``reason`` is a short text naming what is wrong."""

    def __init__(self, reason: str):
        super().__init__(f"not a Live Link Face packet: {reason}")
        self.reason = reason


@dataclass(frozen=True)
class LiveLinkFrame:
    """One packet of the stream.

    Attributes:
        device_id: The sending phone's id.
        subject: The subject name set in the app.
        frame_number: The frame count of the app's timecode at ``rate``.
        sub_frame: Fraction of a frame, in [0, 1).
        rate: (numerator, denominator): ``numerator / denominator`` frames per second.
        channels: (61,) float64, the values as sent (:data:`LIVELINK_CHANNELS` order; angles [rad]).
        received: When the datagram was read [s], ``time.perf_counter()`` clock.
        elapsed: Seconds since the stream's first frame on the source's clock, set by
            :class:`LiveLink` (continuous: where the source's clock jumps back, at midnight or
            when the app restarts, it goes on from the frame before; 0 from :func:`parse_packet`).
    """

    device_id: str
    subject: str
    frame_number: int
    sub_frame: float
    rate: tuple
    channels: np.ndarray = field(repr=False)
    received: float = 0.0
    elapsed: float = 0.0

    @property
    def fps(self) -> float:
        """The stream's frame rate [1/s]."""
        return self.rate[0] / self.rate[1]

    @property
    def time(self) -> float:
        """The frame's time [s] on the app's clock, ``(frame_number + sub_frame) / fps``."""
        return (self.frame_number + self.sub_frame) * self.rate[1] / self.rate[0]

    @property
    def weights(self) -> np.ndarray:
        """(52,) float64 in [0, 1]: the ARKit weights (:data:`~facewarp.ARKIT_NAMES` order), clamped."""
        return np.clip(self.channels[:52], 0.0, 1.0)

    @property
    def clamped(self) -> bool:
        """Some weight was sent outside [0, 1] (and is clamped in :attr:`weights`)."""
        w = self.channels[:52]
        return bool((w < 0.0).any() or (w > 1.0).any())

    @property
    def head_rotation(self) -> np.ndarray:
        """(3,) float64 [rad]: the head's yaw, pitch and roll."""
        return self.channels[52:55].copy()

    @property
    def eyes(self) -> np.ndarray:
        """(6,) float64 [rad]: the left eye's yaw, pitch, roll, then the right eye's."""
        return self.channels[55:61].copy()


def _string(data: bytes, at: int, what: str) -> tuple[str, int]:
    if at + 4 > len(data):
        raise PacketError(f"truncated in the {what}")
    (n,) = struct.unpack_from(">i", data, at)
    at += 4
    if n < 0 or n > MAX_STRING_BYTES:
        raise PacketError(f"{what} of {n} bytes")
    if at + n > len(data):
        raise PacketError(f"{what} of {n} bytes runs past the datagram's end")
    try:
        return data[at:at + n].decode("utf-8"), at + n
    except UnicodeDecodeError:
        raise PacketError(f"{what} is not UTF-8") from None


def parse_packet(data: bytes, *, received: float = 0.0) -> LiveLinkFrame:
    """Read one Live Link Face datagram (the layout in the module docstring).

    Args:
        data: The datagram's bytes.
        received: Its arrival time [s] to keep in the frame.

    Returns:
        The :class:`LiveLinkFrame`.

    Raises:
        PacketError: the datagram is not a valid packet (its ``reason`` says why).
    """
    data = bytes(data)
    if len(data) < MIN_PACKET_BYTES:
        raise PacketError(f"{len(data)} bytes, shorter than the {MIN_PACKET_BYTES} of the smallest packet")
    if data[0] != PACKET_VERSION:
        raise PacketError(f"version {data[0]}, expected {PACKET_VERSION}")
    device, at = _string(data, 1, "device id")
    subject, at = _string(data, at, "subject name")
    if at + _HEADER_TAIL.size + _CHANNELS.size > len(data):
        raise PacketError("truncated after the subject name")
    frame, sub, num, den, count = _HEADER_TAIL.unpack_from(data, at)
    at += _HEADER_TAIL.size
    if count != len(LIVELINK_CHANNELS):
        raise PacketError(f"{count} channels, expected {len(LIVELINK_CHANNELS)}")
    if num <= 0 or den <= 0 or num / den > MAX_RATE:
        raise PacketError(f"frame rate {num}/{den}")
    if not (math.isfinite(sub) and 0.0 <= sub < 1.0):
        raise PacketError(f"sub-frame {sub!r} outside [0, 1)")
    ch = np.array(_CHANNELS.unpack_from(data, at), np.float64)
    if not np.isfinite(ch).all():
        i = int(np.argmin(np.isfinite(ch)))
        raise PacketError(f"channel {LIVELINK_CHANNELS[i]} is {ch[i]!r}")
    w = ch[:52]
    lo, hi = WEIGHT_RANGE
    if (w < lo).any() or (w > hi).any():
        i = int(np.argmax((w < lo) | (w > hi)))
        raise PacketError(f"weight {LIVELINK_CHANNELS[i]} {w[i]:.4g} outside [{lo:g}, {hi:g}]")
    a = ch[52:]
    if (np.abs(a) > math.pi).any():
        i = 52 + int(np.argmax(np.abs(a) > math.pi))
        raise PacketError(f"angle {LIVELINK_CHANNELS[i]} {ch[i]:.4g} rad beyond +-pi")
    return LiveLinkFrame(device, subject, int(frame), float(sub), (int(num), int(den)), ch, float(received))


def encode_packet(weights, *, head=None, eyes=None, frame_number: int = 0, sub_frame: float = 0.0,
                  rate=(60, 1), device_id: str = "facewarp", subject: str = "facewarp") -> bytes:
    """One Live Link Face datagram (the layout in the module docstring), as the app sends it.

    Args:
        weights: (52,) ARKit weights (:data:`~facewarp.ARKIT_NAMES` order).
        head: (3,) head yaw, pitch, roll [rad] (default zeros).
        eyes: (6,) left and right eye yaw, pitch, roll [rad] (default zeros).
        frame_number, sub_frame, rate: The frame's time (``rate`` = (numerator, denominator)).
        device_id, subject: The strings of the packet.

    Returns:
        The datagram's bytes.
    """
    from ..core.checks import check_array

    w = check_array("weights", weights, shape=(52,))
    h = np.zeros(3) if head is None else check_array("head", head, shape=(3,))
    e = np.zeros(6) if eyes is None else check_array("eyes", eyes, shape=(6,))
    dev, sub = str(device_id).encode("utf-8"), str(subject).encode("utf-8")
    return b"".join([bytes([PACKET_VERSION]), struct.pack(">i", len(dev)), dev, struct.pack(">i", len(sub)), sub,
                     _HEADER_TAIL.pack(int(frame_number), float(sub_frame), int(rate[0]), int(rate[1]),
                                       len(LIVELINK_CHANNELS)),
                     _CHANNELS.pack(*np.r_[w, h, e].astype(np.float64))])


# ------------------------------------------------------------------------------------ receiving
@dataclass
class LiveLinkStats:
    """What a :class:`LiveLink` received since it opened.

    Attributes:
        datagrams: Datagrams read from the socket.
        frames: Valid packets of the stream's source taken in (in frame-time order).
        delivered: Frames handed to the consumer (:meth:`LiveLink.receive`, iteration).
        dropped: Frames superseded by a newer one before the consumer asked (it was busy).
        malformed: Datagrams that are not packets (:class:`PacketError`), skipped.
        malformed_reasons: Reason -> count (the first :data:`MAX_REASONS` reasons).
        late: Packets of the source at or before a frame already taken (repeated or out of order), skipped.
        other_source: Packets of another device than the first one heard, skipped.
        missing: Frames the source numbered that never arrived (gaps in its frame numbers).
        clamped: Frames with a weight a little outside [0, 1] (clamped).
        clock_resets: Times the source's clock jumped back by more than :data:`CLOCK_RESET_S`
            (taken as a new clock, the frames' ``elapsed`` continuing).
    """

    datagrams: int = 0
    frames: int = 0
    delivered: int = 0
    dropped: int = 0
    malformed: int = 0
    malformed_reasons: dict = field(default_factory=dict)
    late: int = 0
    other_source: int = 0
    missing: int = 0
    clamped: int = 0
    clock_resets: int = 0

    def as_dict(self) -> dict:
        return {k: (dict(v) if isinstance(v, dict) else v) for k, v in vars(self).items()}

    @property
    def dropped_fraction(self) -> float:
        """``dropped / frames`` (0 before any frame)."""
        return self.dropped / self.frames if self.frames else 0.0


MAX_REASONS = 20
"""Distinct reasons kept in :attr:`LiveLinkStats.malformed_reasons`."""

RECEIVE_BUFFER_BYTES = 1 << 20
"""The socket's receive buffer asked for (the system may give less): some seconds of a 60 fps stream."""

_MAX_DATAGRAM = 65535

CLOCK_RESET_S = 1.0
"""A packet this many seconds or more before the newest frame is a restarted clock, not a late packet."""


def check_port(port) -> int:
    """``port`` as an int in 0..65535 (0: any free port), else :class:`InputError`."""
    if isinstance(port, bool) or not isinstance(port, (int, np.integer)) or not 0 <= int(port) <= 65535:
        raise InputError(f"port: expected a UDP port number 0..65535, got {port!r}")
    return int(port)


class LiveLink:
    """Receive Live Link Face's stream on a UDP port (the iPhone app's "Live Link" target).

    ``with fw.LiveLink(11111) as link:`` binds the port; ``for frame in link:`` gives the
    stream's frames as :class:`LiveLinkFrame` (the ARKit weights, head and eye angles, the
    frame's time), always the newest one: whatever arrived while the loop body ran is read and
    dropped (counted in :attr:`stats`), never queued, so a consumer slower than the stream stays
    on time. Iteration ends when nothing arrives for ``timeout`` seconds. :meth:`receive` is
    the same one frame at a time. The first device heard is the source; packets of another
    phone on the same port are counted and skipped, as are malformed datagrams, and packets
    older than a frame already taken.

    Args:
        port: UDP port, 0..65535 (default 11111, the app's; 0: any free port, see :attr:`port`).
        host: Address to bind (default ``"0.0.0.0"``: every interface; ``"127.0.0.1"``: this machine only).
        timeout: Seconds without a packet that end iteration (default 10; None: wait forever).
        keep: Keep every frame taken in (:attr:`history`, :meth:`save_csv`), not only the newest.

    Attributes:
        stats: The :class:`LiveLinkStats`.
        history: Every frame taken in, in frame-time order (with ``keep=True``).
        device_id: The source's device id (None before the first packet).

    Reading and writing single packets (a captured datagram, a test stream): :meth:`parse`,
    :meth:`packet`; :attr:`CHANNELS` names the 61 channels.

    Raises:
        InputError: a bad port or host, a port in use or not allowed (one line).
    """

    CHANNELS = LIVELINK_CHANNELS
    """The 61 channels of a packet, in order (the 52 ARKit weights, head yaw/pitch/roll, eyes)."""

    parse = staticmethod(parse_packet)
    packet = staticmethod(encode_packet)

    def __init__(self, port: int = DEFAULT_PORT, *, host: str = "0.0.0.0", timeout: float | None = 10.0,
                 keep: bool = False):
        from ..core.checks import check_bool, check_number

        port = check_port(port)
        if not isinstance(host, str) or not host:
            raise InputError(f"host: expected an IP address or host name, got {host!r}")
        self.timeout = None if timeout is None else check_number("timeout", timeout, low=0.0, low_open=True)
        self.keep = check_bool("keep", keep)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
            except OSError:
                pass  # the system's default buffer then
            sock.bind((host, port))
        except (OSError, OverflowError) as e:
            sock.close()
            raise InputError(_bind_error(host, port, e)) from None
        sock.setblocking(False)
        self._sock = sock
        self.host = host
        self.port = int(sock.getsockname()[1])
        self.stats = LiveLinkStats()
        self.history: list[LiveLinkFrame] = []
        self.device_id: str | None = None
        self._pending: LiveLinkFrame | None = None  # the newest frame taken in, not yet delivered
        self._last: LiveLinkFrame | None = None  # the newest frame taken in
        self._offset = 0.0  # [s] a frame's elapsed = its time + this
        self._closed = False

    # ---------------------------------------------------------------- socket
    def close(self) -> None:
        """Close the socket (the port is free again)."""
        if not self._closed:
            self._sock.close()
            self._closed = True

    @property
    def closed(self) -> bool:
        """The socket is closed."""
        return self._closed

    @property
    def last(self) -> LiveLinkFrame | None:
        """The newest frame taken in (delivered or not), None before the first."""
        return self._last

    def __enter__(self) -> LiveLink:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

    def _check_open(self) -> None:
        if self._closed:
            raise InputError("LiveLink: the socket is closed")

    # ---------------------------------------------------------------- taking packets in
    def _take(self, data: bytes, now: float) -> None:
        st = self.stats
        st.datagrams += 1
        try:
            fr = parse_packet(data, received=now)
        except PacketError as e:
            st.malformed += 1
            key = e.reason
            if key in st.malformed_reasons or len(st.malformed_reasons) < MAX_REASONS:
                st.malformed_reasons[key] = st.malformed_reasons.get(key, 0) + 1
            return
        if self.device_id is None:
            self.device_id = fr.device_id
        elif fr.device_id != self.device_id:
            st.other_source += 1
            return
        last = self._last
        if last is None:
            self._offset = -fr.time  # elapsed = time + offset
        else:
            if fr.rate == last.rate:
                gap = fr.frame_number - last.frame_number
                newer = gap > 0 or (gap == 0 and fr.sub_frame > last.sub_frame)
            else:  # the app's rate changed: compare times
                gap, newer = None, fr.time > last.time
            if not newer and last.time - fr.time >= CLOCK_RESET_S:  # a new clock: go on from the last frame
                st.clock_resets += 1
                self._offset = last.elapsed + 1.0 / fr.fps - fr.time
                gap, newer = None, True
            if not newer:
                st.late += 1
                return
            if gap is not None and gap > 1:
                st.missing += gap - 1
        fr = replace(fr, elapsed=fr.time + self._offset)
        st.frames += 1
        if fr.clamped:
            st.clamped += 1
        if self._pending is not None:
            st.dropped += 1  # superseded before the consumer asked for it
        self._pending = self._last = fr
        if self.keep:
            self.history.append(fr)

    def flush(self) -> int:
        """Discard what waits on the socket, uncounted (packets from before the consumer was
        ready: not part of the take); returns how many datagrams."""
        self._check_open()
        n = 0
        while True:
            try:
                self._sock.recv(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return n
            except ConnectionResetError:
                continue
            n += 1

    def poll(self) -> int:
        """Read every datagram waiting on the socket without blocking; returns how many."""
        self._check_open()
        n = 0
        while True:
            try:
                data = self._sock.recv(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return n
            except ConnectionResetError:  # an ICMP error of an earlier send on some systems: not data
                continue
            n += 1
            self._take(data, time.perf_counter())

    def receive(self, timeout: float | None = None) -> LiveLinkFrame | None:
        """The newest frame of the stream: what waits on the socket is read (the older frames
        dropped); if no frame is new since the last call, wait up to ``timeout`` seconds
        (default the link's; 0: do not wait) for one.

        Returns:
            The :class:`LiveLinkFrame`, or None when nothing new arrived in time.
        """
        import select

        self._check_open()
        wait = self.timeout if timeout is None else timeout
        end = None if wait is None else time.perf_counter() + max(float(wait), 0.0)
        self.poll()
        while self._pending is None:
            left = None if end is None else end - time.perf_counter()
            if left is not None and left <= 0:
                return None
            ready, _, _ = select.select([self._sock], [], [], left)
            if ready:
                self.poll()
        fr, self._pending = self._pending, None
        self.stats.delivered += 1
        return fr

    def __iter__(self):
        while True:
            fr = self.receive()
            if fr is None:
                return
            yield fr

    # ---------------------------------------------------------------- the take
    def save_csv(self, path) -> Path:
        """Write every frame taken in (:attr:`history`; needs ``keep=True``) as a Live Link Face
        CSV (:func:`write_livelink_csv`)."""
        if not self.keep:
            raise InputError("save_csv: the LiveLink was opened without keep=True (it kept no history)")
        return write_livelink_csv(self.history, path)


def _bind_error(host: str, port: int, e: Exception) -> str:
    code = getattr(e, "errno", None)
    if code == errno.EADDRINUSE:
        return (f"port {port}: in use by another program (a second facewarp live, or Unreal's Live Link?); "
                "choose another")
    if code == errno.EACCES:
        return f"port {port}: not allowed (ports below 1024 need administrator rights); choose another"
    if code == errno.EADDRNOTAVAIL:
        return f"host {host}: not an address of this machine"
    if isinstance(e, (socket.gaierror, OverflowError)):
        return f"host {host!r}, port {port}: {e}"
    return f"port {port} on {host}: cannot listen ({getattr(e, 'strerror', None) or e})"


def write_livelink_csv(frames, path) -> Path:
    """Frames of the stream as a Live Link Face CSV (the columns the app writes), atomically.

    ``Timecode`` is ``HH:MM:SS:FF.fff`` from each frame's frame number and sub-frame at its
    rate (the app's timecode as it sent it; after a clock reset, the first frame's clock continued
    by :attr:`LiveLinkFrame.elapsed`), ``BlendShapeCount`` 61, then the 61 channels as
    sent (:data:`LIVELINK_CHANNELS`; the shortest decimals that give the packet's float32 back).
    :func:`~facewarp.load_arkit` reads it.

    Args:
        frames: :class:`LiveLinkFrame` objects in time order (at least one).
        path: The ``.csv`` file.
    """
    import csv
    import io

    from ..core.checks import check_path
    from ..core.fileio import atomic_write

    frames = list(frames)
    if not frames or not all(isinstance(f, LiveLinkFrame) for f in frames):
        raise InputError("frames: expected one or more LiveLinkFrame objects")
    path = check_path("path", path)
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["Timecode", "BlendShapeCount", *LIVELINK_CHANNELS])
    t0 = frames[0].time - frames[0].elapsed  # the first frame's clock; elapsed continues it past clock resets
    for f in frames:
        rate = max(1, int(round(f.fps)))  # timecode frames per second
        ticks = int(round((t0 + f.elapsed) * rate * 1000.0))  # thousandths of a timecode frame
        whole, sub = divmod(ticks, 1000)
        secs, ff = divmod(whole, rate)
        tc = f"{secs // 3600:02d}:{secs // 60 % 60:02d}:{secs % 60:02d}:{ff:02d}.{sub:03d}"
        w.writerow([tc, len(LIVELINK_CHANNELS), *(str(np.float32(v)) for v in f.channels)])  # float32 exactly
    with atomic_write(path, "w") as fh:
        fh.write(out.getvalue())
    return Path(path)
