"""Where a run reads and writes: standard input and output as ``-``, a TCP source, outputs that
replace a file only once the run has started, inputs and outputs checked apart before anything is
opened, SIGINT and SIGTERM turned into exceptions that let a run close what it opened, and a replay
paced at stream time.

* :func:`open_observations`: ``-`` (standard input), ``tcp://HOST:PORT`` (a connection to a tracker
  that serves JSON Lines) or a path (a file or a FIFO, opened by the reader).
* :func:`check_paths`: an output that is one of the inputs, or another output (the same file by
  path, symbolic link or hard link), or two options on the same standard stream, is refused with a
  located error (:class:`~physics.errors.InputError`) before any file is opened.
* :class:`StagedFile` and :class:`LineOutput`: a regular file is written beside its path (a hidden
  ``.NAME.XXXX.partial``) and takes the path's place at :meth:`StagedFile.commit`, when the run has
  started cleanly; a run that fails before leaves an existing file as it was. FIFOs and devices
  are written directly, opened only then.
* :class:`StopSignals`: SIGINT raises :class:`KeyboardInterrupt` and SIGTERM :class:`Terminated`
  in the main thread, except inside :meth:`StopSignals.deferred` (writing a line, closing the run),
  after which a signal that came meanwhile is raised.
* :func:`paced`: frames made available at wall time ``start + t / speed`` (``--realtime``).
"""
from __future__ import annotations

import contextlib
import os
import signal
import socket
import stat
import sys
import tempfile
import time
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator, TextIO

from physics.errors import InputError

STDIO = "-"
"""The file name that means standard input (for an input) or standard output (for an output)."""
STDIN_NAME = "<stdin>"
"""How standard input is named in error messages (``<stdin>:5: objects.cup.position: ...``)."""
TCP_PREFIX = "tcp://"

EXIT_SIGINT = 130
"""Exit status of a run ended by SIGINT (Ctrl-C): 128 + 2, as shells report it."""
EXIT_SIGTERM = 143
"""Exit status of a run ended by SIGTERM (systemd, docker, roslaunch): 128 + 15."""


# -- inputs ---------------------------------------------------------------------------------------
def parse_tcp(spec: str, option: str = "--observations") -> tuple[str, int] | None:
    """``(host, port)`` of a ``tcp://HOST:PORT`` source (``[::1]`` for an IPv6 host); None for any
    other spec. A malformed one is an :class:`InputError` naming ``option``."""
    if not spec.startswith(TCP_PREFIX):
        return None
    rest = spec[len(TCP_PREFIX):].rstrip("/")
    host, sep, port = rest.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise InputError(f"expected tcp://HOST:PORT, got {spec!r}", field=option)
    return host, int(port)


def open_observations(spec: str, timeout: float = 10.0) -> tuple[str, TextIO | None]:
    """The name an observation source has in messages and its open text stream: ``-`` is standard
    input (``<stdin>``), ``tcp://HOST:PORT`` a connection to it (``timeout`` s to connect; then
    lines are read as they come, without a timeout); a path gives ``(path, None)``: the reader opens
    it (a FIFO then blocks until a writer opens it). A refused connection is an :class:`InputError`."""
    if spec == STDIO:
        try:  # a file object of its own: a reader thread blocked on it cannot hold sys.stdin's lock at exit
            return STDIN_NAME, os.fdopen(os.dup(sys.stdin.fileno()), "r", encoding="utf-8")
        except (AttributeError, OSError, ValueError):  # no descriptor (an embedding application's stdin)
            return STDIN_NAME, sys.stdin
    addr = parse_tcp(spec)
    if addr is None:
        return spec, None
    try:
        sock = socket.create_connection(addr, timeout=timeout)
    except OSError as exc:
        raise InputError(f"cannot connect to {spec}: {exc.strerror or exc}", field="--observations") from None
    sock.settimeout(None)
    stream = sock.makefile("r", encoding="utf-8", newline="\n")
    sock.close()  # the file keeps the connection open until it is closed
    return spec, stream


# -- inputs and outputs apart ---------------------------------------------------------------------
@dataclass(frozen=True)
class PathOption:
    """A file option of a command: its name (``--out``) and its value (None: not given)."""

    option: str
    value: str | None


def _identity(path: str) -> tuple:
    """What makes two paths the same file: device and inode when it exists (links followed),
    else its absolute path with the folders' links resolved."""
    try:
        st = os.stat(path)
    except OSError:
        return ("path", os.path.realpath(path))
    return ("inode", st.st_dev, st.st_ino)


def _is_device(path: str) -> bool:
    try:
        return stat.S_ISCHR(os.stat(path).st_mode)
    except OSError:
        return False


def check_paths(inputs: Iterable[PathOption], outputs: Iterable[PathOption]) -> None:
    """Refuse, before any file is opened, an output that is one of the inputs or another output
    (the same file: the same path, or through a symbolic or a hard link) and two options on the same
    standard stream (``-``); ``tcp://`` sources and character devices (``/dev/null``) are not files.
    Raises :class:`InputError` naming the output's option."""
    inputs = [o for o in inputs if o.value is not None]
    outputs = [o for o in outputs if o.value is not None]
    std_in = [o for o in inputs if o.value == STDIO]
    if len(std_in) > 1:
        raise InputError(f"standard input (-) is already {std_in[0].option}", field=std_in[1].option)
    seen: dict[tuple, PathOption] = {}
    for o in inputs:
        if o.value != STDIO and parse_tcp(o.value, o.option) is None and not _is_device(o.value):
            seen.setdefault(_identity(o.value), o)
    std_out = None
    for o in outputs:
        if o.value == STDIO:
            if std_out is not None:
                raise InputError(f"standard output (-) is already {std_out.option}", field=o.option)
            std_out = o
            continue
        if _is_device(o.value):
            continue
        key = _identity(o.value)
        other = seen.get(key)
        if other is not None:
            what = "an input" if other in inputs else "another output"
            raise InputError(f"{o.value} is the same file as {other.option} {other.value} ({what}): refusing to "
                             "write over it", field=o.option)
        seen[key] = o


# -- outputs --------------------------------------------------------------------------------------
class StagedFile:
    """An output path that what a run writes replaces only once the run has started.

    A regular file (or a path that does not exist yet) is written to a hidden file in the same folder
    (:attr:`write_path`, created now, so that an unwritable folder is an error before the run), which
    :meth:`commit` renames onto the path (what is open on it stays open: later writes go to the
    renamed file); :meth:`discard` removes it if it was never committed. A symbolic link is followed
    (its target is replaced, the link kept). A path that is not a regular file (a FIFO, a device) is
    written directly: :attr:`write_path` is the path itself, to be opened only once the run started.
    """

    def __init__(self, path: str, option: str = "output"):
        self.path = os.path.realpath(path)
        self.option = option
        self.committed = False
        try:
            mode = os.stat(self.path).st_mode
        except FileNotFoundError:
            mode = None
        except OSError as exc:
            raise InputError(f"cannot write {path}: {exc.strerror}", field=option) from None
        self.direct = mode is not None and not stat.S_ISREG(mode)
        self._staging: str | None = None
        if self.direct:
            return
        folder, name = os.path.split(self.path)
        try:
            fd, self._staging = tempfile.mkstemp(prefix=f".{name}.", suffix=".partial", dir=folder)
        except OSError as exc:
            raise InputError(f"cannot write {path}: {exc.strerror} ({folder})", field=option) from None
        os.close(fd)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(self._staging, stat.S_IMODE(mode) if mode is not None else 0o666 & ~umask)

    @property
    def write_path(self) -> str:
        """Where to write now: the hidden staging file, or the path itself when written directly."""
        return self.path if self._staging is None else self._staging

    def commit(self) -> None:
        """The run has started: the staging file takes the path's place (once; no-op when direct)."""
        if self._staging is not None and not self.committed:
            os.replace(self._staging, self.path)
        self.committed = True

    def discard(self) -> None:
        """Remove the staging file if it never took the path's place (the path is left as it was)."""
        if self._staging is not None and not self.committed:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self._staging)
            self._staging = None


class LineOutput:
    """A stream of JSON lines (estimates) to a file, a FIFO or standard output (``-``), each line
    written and flushed at once. A file is staged (:class:`StagedFile`) until :meth:`start`; a FIFO
    is opened at :meth:`start`. :meth:`close` after :meth:`start` keeps what was written, before it
    leaves the path as it was. A reader that went away raises :class:`BrokenPipeError` from
    :meth:`write`."""

    def __init__(self, spec: str, option: str = "--out"):
        self.spec = spec
        self.is_stdout = spec == STDIO
        self._staged = None if self.is_stdout else StagedFile(spec, option)
        self._fh: TextIO | None = None
        if self._staged is not None and not self._staged.direct:
            self._fh = open(self._staged.write_path, "w", encoding="utf-8")
        self.started = False

    def start(self) -> None:
        """The run started cleanly: the output takes its path's place (or is opened)."""
        if self.started:
            return
        self.started = True
        if self.is_stdout:
            self._fh = sys.stdout
        elif self._staged.direct:
            self._fh = open(self._staged.write_path, "w", encoding="utf-8")
        else:
            self._staged.commit()

    def write(self, line: str) -> None:
        """Write one line (``line`` without its newline) and flush it."""
        self._fh.write(line + "\n")
        self._fh.flush()

    def close(self) -> None:
        """Close the output (standard output is flushed, not closed); never started: the path is left
        as it was."""
        fh, self._fh = self._fh, None
        if fh is not None and fh is not sys.stdout:
            with contextlib.suppress(BrokenPipeError):
                fh.close()
        if self._staged is not None and not self.started:
            self._staged.discard()


def write_text(spec: str, text: str, option: str = "output") -> None:
    """Write a whole document (the timeline) to ``spec``: ``-`` is standard output (flushed); a
    regular file is replaced at once when the text is complete (written beside it, then renamed: an
    interruption never leaves half a document)."""
    if spec == STDIO:
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    staged = StagedFile(spec, option)
    try:
        with open(staged.write_path, "w", encoding="utf-8") as fh:
            fh.write(text)
        staged.commit()
    finally:
        staged.discard()


def silence_stdout() -> None:
    """Point standard output at ``/dev/null`` after its reader went away (``| head``), so that the
    interpreter's last flush at exit does not report a broken pipe."""
    with contextlib.suppress(OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


# -- signals --------------------------------------------------------------------------------------
class Terminated(BaseException):
    """SIGTERM arrived (raised in the main thread by :class:`StopSignals`, as SIGINT raises
    :class:`KeyboardInterrupt`)."""


class StopSignals:
    """While installed (a context manager, main thread only), SIGINT raises
    :class:`KeyboardInterrupt` and SIGTERM :class:`Terminated` where the main thread is, blocking
    reads and waits included, except inside :meth:`deferred`: there a signal is remembered and
    raised when the outermost :meth:`deferred` block ends (a line is written whole, the timeline
    written whole, worker processes closed). The previous handlers are put back on exit."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self._depth = 0
        self._pending: int | None = None
        self._previous: dict[int, object] = {}

    def __enter__(self) -> "StopSignals":
        for s in self.SIGNALS:
            self._previous[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for s, h in self._previous.items():
            signal.signal(s, h)
        self._previous = {}

    @staticmethod
    def exception(signum: int) -> BaseException:
        return KeyboardInterrupt() if signum == signal.SIGINT else Terminated()

    def _handle(self, signum, frame) -> None:
        if self._depth:
            if self._pending is None:
                self._pending = signum
            return
        raise self.exception(signum)

    @contextlib.contextmanager
    def deferred(self) -> Iterator[None]:
        """A block that a signal does not interrupt; the signal is raised at its end."""
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1
            if self._depth == 0 and self._pending is not None:
                signum, self._pending = self._pending, None
                raise self.exception(signum)


# -- pacing ---------------------------------------------------------------------------------------
def paced(frames: Iterable, speed: float = 1.0, clock: Callable[[], float] = time.monotonic,
          sleep: Callable[[float], None] = time.sleep) -> Iterator:
    """The frames of ``frames`` (anything with a ``t`` in seconds), each yielded no earlier than wall
    time ``start + (t - t_first) / speed`` on ``clock`` (``start``: when the first one is read); a
    frame that is late already is yielded at once. Nothing is read ahead of the frame waited for."""
    if not speed > 0:
        raise ValueError(f"speed must be > 0, got {speed}")
    start = t0 = None
    for frame in frames:
        if start is None:
            start, t0 = clock(), frame.t
        wait = start + (frame.t - t0) / speed - clock()
        if wait > 0:
            sleep(wait)
        yield frame
