"""The dynamic gate in a child Python process, beside tracking (``gating.worker: process``).

A worker thread shares the interpreter lock with tracking, so the gate's Python work and the
tracker's take turns; a child process runs them side by side. Frames go to the child and
masks come back through a shared memory buffer; calls, timings and the child's log records
go through a socket. The child is started with ``python -m`` rather than ``multiprocessing``,
so it never re-imports the caller's script.
"""

from __future__ import annotations

import contextlib
import logging
import mmap
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection

import cv2
import numpy as np

from osslam.config import Config
from osslam.errors import OsslamError
from osslam.timing import peak_rss_mb
from osslam.types import CameraIntrinsics

from .gating import DynamicGate, gate_cost

WORKERS = ("process", "thread")


class GateWorkerError(OsslamError):
    """The gate's worker process ended without answering."""


@dataclass
class GateOutput:
    """What tracking and mapping take from one frame's gate: its masks, timings and how it was made.

    The fields are those of :class:`~osslam.frontend.gating.GateResult` without the
    segmentation and fusion themselves; the map's mask is only made for a map.
    """

    mask: np.ndarray
    map_mask: np.ndarray | None  # None with mapping off
    moving_now: np.ndarray | None
    timings_ms: dict[str, float]
    predicted: bool
    segmented: bool

    @property
    def cost_ms(self) -> float:
        """The gate's time for the frame: its stages together."""
        return gate_cost(self.timings_ms)


def open_gate(cfg: Config, intrinsics: CameraIntrinsics) -> DynamicGate | GateProcess:
    """The dynamic gate of ``gating.worker``: in a child process, or on a thread of this one."""
    if cfg.gating.worker not in WORKERS:
        raise ValueError(f"gating.worker '{cfg.gating.worker}' unknown ({', '.join(WORKERS)})")
    if cfg.gating.worker == "thread":
        return DynamicGate(cfg, intrinsics)
    return GateProcess(cfg, intrinsics)


class _Buffer:
    """Numpy views of one frame's images, the motions :meth:`GateProcess.finish` is given and its masks, shared."""

    MASKS = ("mask", "map_mask", "moving_now", "prior")

    def __init__(self, height: int, width: int, memory):
        self.shape = (height, width)
        self.views: dict[str, np.ndarray] = {}
        offset = 0
        for name, shape, dtype in self._fields(height, width):
            self.views[name] = np.ndarray(shape, dtype, memory, offset)
            offset += self.views[name].nbytes

    @staticmethod
    def _fields(height: int, width: int) -> tuple:
        """(name, shape, dtype) of each view, in the buffer's order."""
        return (("motions", (3, 4, 4), np.float64),  # ego-motion, guess, pose (pickled, slower)
                ("depth", (8 * height * width,), np.uint8),  # room for float64 metres, aligned
                ("rgb", (height, width, 3), np.uint8), ("gray", (height, width), np.uint8),
                *((m, (height, width), np.bool_) for m in _Buffer.MASKS))

    @staticmethod
    def size(height: int, width: int) -> int:
        """Bytes of the buffer for images of ``height`` x ``width``."""
        return sum(int(np.prod(shape)) * np.dtype(dtype).itemsize for _, shape, dtype in _Buffer._fields(height, width))

    def depth(self, dtype: str) -> np.ndarray:
        """The depth image's view as floats of ``dtype``."""
        count = self.shape[0] * self.shape[1] * np.dtype(dtype).itemsize
        return self.views["depth"][:count].view(dtype).reshape(self.shape)


class GateProcess:
    """A :class:`~osslam.frontend.gating.DynamicGate` run in a child process: the same calls.

    :meth:`finish` returns a :class:`GateOutput`. The child starts (and builds the gate,
    loading its models) before the constructor returns; errors there and later are raised
    here, and the child's log records are logged here under their own names.
    ``peak_rss_mb`` is the child's peak resident memory as of its last answer.
    """

    def __init__(self, cfg: Config, intrinsics: CameraIntrinsics):
        self._file = tempfile.TemporaryFile(dir="/dev/shm" if os.path.isdir("/dev/shm") else None)
        size = _Buffer.size(intrinsics.height, intrinsics.width)
        os.ftruncate(self._file.fileno(), size)
        self._memory = mmap.mmap(self._file.fileno(), size)
        self._buffer = _Buffer(intrinsics.height, intrinsics.width, self._memory)
        ours, theirs = socket.socketpair()
        with ours, theirs:
            self._process = subprocess.Popen(
                [sys.executable, "-m", __name__, str(theirs.fileno()), str(self._file.fileno())],
                pass_fds=(theirs.fileno(), self._file.fileno()))
            self._conn = Connection(os.dup(ours.fileno()))
        self._prior: np.ndarray | None = None
        self._prior_due = False  # the child sends each finished frame's prior after its mask
        self._wants_colour = True  # whether the next frame's detection needs its colour image, as the child says
        try:
            self._send((cfg, intrinsics, logging.getLogger().getEffectiveLevel()))
            (self.peak_rss_mb,) = self._reply("ready")
        except BaseException:
            self._release()
            raise

    def start(self, rgb: np.ndarray, gray: np.ndarray, depth: np.ndarray) -> None:
        """Send a new frame to the child, which begins its flow and detection.

        The colour image goes only to frames the detector runs on (see :attr:`DynamicGate.wants_colour`).
        """
        views = self._buffer.views
        if self._wants_colour:
            views["rgb"][:] = rgb
        views["gray"][:] = gray
        self._buffer.depth(depth.dtype.name)[:] = depth
        self._send(("start", depth.dtype.name, self._wants_colour))

    def finish(self, ego_motion: np.ndarray | None = None, guess: np.ndarray | None = None,
               pose: np.ndarray | None = None) -> GateOutput:
        """The dynamic mask of the started frame: see :meth:`DynamicGate.finish`."""
        self._take_prior()
        motions = (ego_motion, guess, pose)
        for i, motion in enumerate(motions):
            if motion is not None:
                self._buffer.views["motions"][i] = motion
        self._send(("finish", tuple(m is not None for m in motions)))
        timings, predicted, segmented, has_map, has_moving, self._wants_colour, self.peak_rss_mb = self._reply("result")
        self._prior_due = True
        views = self._buffer.views
        return GateOutput(views["mask"].copy(), views["map_mask"].copy() if has_map else None,
                          views["moving_now"].copy() if has_moving else None, timings, predicted, segmented)

    def prior(self) -> np.ndarray | None:
        """Where movers may be in the next frame: see :meth:`DynamicGate.prior`."""
        self._take_prior()
        return self._prior

    def _take_prior(self) -> None:
        """Read the prior the child sends once it has kept the last finished frame."""
        if self._prior_due:
            self._prior_due = False
            (given,) = self._reply("prior")
            self._prior = self._buffer.views["prior"].copy() if given else None

    def close(self) -> None:
        """Stop the child and free the buffer."""
        try:
            if self._process.poll() is None:
                self._send(("close",))
                self._reply("closed", skip=("result", "prior"))  # answers an interrupted caller left unread
        except GateWorkerError:
            pass  # the child has ended already: nothing left to stop
        finally:
            self._release()

    def _release(self) -> None:
        """Wait for the child to end, then close the socket and the buffer."""
        self._conn.close()  # a child still waiting for a call reads the end of its input, and ends
        self._process.wait()
        self._memory.close()
        self._file.close()

    def _send(self, message) -> None:
        try:
            self._conn.send(message)
        except OSError:
            raise self._ended() from None

    def _reply(self, kind: str, skip: tuple[str, ...] = ()) -> tuple:
        """The items of the child's answer of ``kind``; log records on the way are logged, errors raised.

        Answers of the kinds in ``skip`` are passed over.
        """
        while True:
            try:
                message = self._conn.recv()
            except (EOFError, OSError):
                raise self._ended() from None
            if message[0] == "log":
                logging.getLogger(message[1]).log(message[2], "%s", message[3])
            elif message[0] == "error":
                self._process.wait()
                raise _rebuilt(*message[1:])
            elif message[0] == kind:
                return message[1:]
            elif message[0] not in skip:
                raise GateWorkerError(f"the gate's worker process answered {message[0]!r}, not {kind!r}")

    def _ended(self) -> GateWorkerError:
        return GateWorkerError(f"the gate's worker process ended without answering "
                               f"(exit code {self._process.wait()})")


def _rebuilt(kind: str, message: str, text: str) -> Exception:
    """The parent's exception for the child's: a one-line error for bad input or settings, else with its traceback."""
    if kind == "osslam":
        return GateWorkerError(message)
    error = ValueError(message) if kind == "value" else RuntimeError(message)
    error.add_note(f"raised in the gate's worker process:\n{text}")
    return error


class _Forward(logging.Handler):
    """Sends log records to the parent as (name, level, message)."""

    def __init__(self, send):
        super().__init__()
        self._send = send

    def emit(self, record: logging.LogRecord) -> None:
        self._send(("log", record.name, record.levelno, self.format(record)))


def _serve(conn: Connection, memory) -> None:
    """The child's loop: build the gate, then answer start, finish and close until closed."""
    lock = threading.Lock()  # the gate's worker thread logs too

    def send(message) -> None:
        with lock:
            conn.send(message)

    try:
        cfg, intrinsics, level = conn.recv()
        root = logging.getLogger()
        root.handlers[:] = [_Forward(send)]
        root.setLevel(level)
        buffer = _Buffer(intrinsics.height, intrinsics.width, memory)
        views = buffer.views
        cv2.setNumThreads(cfg.run.threads)
        cv2.setRNGSeed(cfg.run.seed)
        gate = DynamicGate(cfg, intrinsics)
        send(("ready", peak_rss_mb()))
        while True:
            message = conn.recv()
            if message[0] == "start":
                gate.start(views["rgb"].copy() if message[2] else None, views["gray"].copy(),
                           buffer.depth(message[1]).copy())
            elif message[0] == "finish":
                result = gate.finish(*(views["motions"][i].copy() if given else None
                                       for i, given in enumerate(message[1])), defer_keep=True)
                views["mask"][:] = result.mask
                if cfg.mapping.enabled:
                    views["map_mask"][:] = result.map_mask
                moving = result.moving_now
                if moving is not None:
                    views["moving_now"][:] = moving
                send(("result", result.timings_ms, result.predicted, result.segmented, cfg.mapping.enabled,
                      moving is not None, gate.wants_colour, peak_rss_mb()))
                prior = gate.prior()  # kept after the result, while the parent goes on
                if prior is not None:
                    views["prior"][:] = prior
                send(("prior", prior is not None))
            else:
                gate.close()
                send(("closed",))
                return
    except (EOFError, ConnectionError):  # the parent closed the socket, or ended with answers unread
        return
    except Exception as error:  # every failure goes back to the parent, which raises it
        kind = "osslam" if isinstance(error, OsslamError) else "value" if isinstance(error, ValueError) else "other"
        with contextlib.suppress(ConnectionError):  # unless the parent has gone meanwhile
            send(("error", kind, f"{error}" if kind != "other" else f"{type(error).__name__}: {error}",
                  traceback.format_exc()))


def main(argv: list[str]) -> None:
    """Entry of the child process: ``python -m osslam.frontend.gate_process SOCKET_FD BUFFER_FD``.

    Ctrl-C reaches the parent alone, which then closes the child.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    conn = Connection(int(argv[0]))
    fd = int(argv[1])
    memory = mmap.mmap(fd, os.fstat(fd).st_size)
    _serve(conn, memory)


if __name__ == "__main__":
    main(sys.argv[1:])
