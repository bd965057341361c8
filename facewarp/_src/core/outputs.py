"""Whole outputs or none: staged output paths, a lock per output, and signals as exceptions.

Every command that writes files runs inside :func:`staged_outputs`. Each output it names (a
folder such as ``adapt --out DIR``, or a file such as ``simulate --out anim.usdc``) is replaced
for the job by a hidden temporary sibling:

- a folder ``DIR`` becomes ``.DIR.facewarp-partial-PID`` (the job writes into it as into ``DIR``);
- a file ``F`` becomes ``.F.facewarp-partial-PID/F`` (files the job writes beside ``F``, such as
  a picture ``F.png``, land in that folder too).

Only when the job has finished are the staged files moved into place: a folder that did not
exist is renamed in one step (atomic on POSIX); into an existing folder each entry is moved with
:func:`os.replace`. If the job raises, or a signal arrives, the staged paths are deleted and the
destination is left as it was. Paths inside the job's result and inside the text files it wrote
(``report.json`` listing its files) name the staged path; :meth:`Staging.unstage` turns them back
into the destination's.

A lock file ``.NAME.facewarp-lock`` beside each output (``fcntl.flock``, released by the kernel
when the process dies) makes a second run on the same output refuse with one line.

:func:`signals_as_exceptions` turns SIGINT and SIGTERM into :class:`Interrupted` (a
``KeyboardInterrupt``; one that lands inside an import is raised when the import is over, since a
compiled module's init would turn it into an ``ImportError``) and remembers that they came, so that a library that swallows the
exception (USD's Python bindings turn it into a warning in some callbacks) cannot make an
interrupted run look finished: :func:`raise_if_interrupted` raises again at the next progress
callback, and the CLI checks :func:`interrupted_by` once the job returns.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from .errors import InputError

__all__ = ["Interrupted", "Staging", "destination", "interrupted_by", "output_lock", "raise_if_interrupted", "signals_as_exceptions",
           "signals_deferred", "staged_outputs"]

PARTIAL_TAG = ".facewarp-partial-"
"""Staged outputs are hidden siblings ``.NAME`` + this + the process id."""

LOCK_SUFFIX = ".facewarp-lock"
"""The lock file beside an output is ``.NAME`` + this."""

TEXT_SUFFIXES = (".json", ".xml", ".usda", ".txt", ".mtl", ".csv")
"""Written files whose text may name the staged path (rewritten to the destination's at commit)."""

MAX_REWRITE_BYTES = 64 * 1024 * 1024
"""Text files larger than this are not searched for staged paths."""


# ----------------------------------------------------------------------------- signals
class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived; ``signum`` says which (exit code 128 + signum)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


_received: list[int] = []


def interrupted_by() -> int | None:
    """The first signal that arrived while :func:`signals_as_exceptions` was active, else None."""
    return _received[0] if _received else None


def raise_if_interrupted() -> None:
    """Raise :class:`Interrupted` again when a signal arrived (for progress callbacks)."""
    if _received:
        raise Interrupted(_received[0])


RETRY_SECONDS = 0.02
"""While an import runs, a signal is raised this long after it, or when the import has ended."""


def _importing(frame) -> bool:
    """Whether ``frame`` runs inside an import (a module's top level, or importlib's own code)."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _handler(signum, frame):
    _received.append(signum)
    if _importing(frame):
        # Raised inside an import, the interrupt can come out as another error: a C extension's
        # module init (NumPy's ``import_array`` in every compiled module of SciPy and others) turns
        # any exception into ``ImportError: ... failed to import`` -- an internal error (exit 1)
        # instead of exit 130 / 143. Raise it once the import is over (SIGALRM retries).
        _arm_retry()
        return
    raise Interrupted(signum)


def _arm_retry() -> None:
    try:
        signal.setitimer(signal.ITIMER_REAL, RETRY_SECONDS)
    except (AttributeError, OSError, ValueError):  # no interval timers here: the next check raises it
        pass


def _retry(signum, frame):
    if not _received:
        return
    if _importing(frame):
        _arm_retry()
        return
    raise Interrupted(_received[0])


@contextlib.contextmanager
def signals_as_exceptions() -> Iterator[None]:
    """SIGINT and SIGTERM raise :class:`Interrupted` in the main thread while the body runs.

    The previous handlers come back afterwards. Outside the main thread (where Python cannot
    install handlers) this does nothing.
    """
    _received.clear()
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    for s in old:
        signal.signal(s, _handler)
    alarm = getattr(signal, "SIGALRM", None)
    old_alarm = signal.signal(alarm, _retry) if alarm is not None else None
    try:
        yield
    finally:
        if alarm is not None:
            with contextlib.suppress(AttributeError, OSError, ValueError):
                signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(alarm, old_alarm if old_alarm is not None else signal.SIG_DFL)
        for s, h in old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """SIGINT / SIGTERM held back while the body runs (the commit's renames; a native library's
    import, whose loader would catch the interrupt and print its own traceback); they are delivered
    afterwards (and by then the output is whole, or the library loaded)."""
    sigs = {signal.SIGINT, signal.SIGTERM}
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    except (AttributeError, OSError, ValueError):
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


# ----------------------------------------------------------------------------- staging
@dataclass
class _Target:
    name: str  # the argument ("out", "build")
    path: Path  # the destination the user asked for
    kind: str  # "dir" or "file"
    dest: Path = field(init=False)  # absolute-safe destination (a name to put beside)
    stage_root: Path = field(init=False)  # the hidden folder this run writes into
    staged: Path = field(init=False)  # what the job gets instead of ``path``
    lock_fd: int | None = None
    created_parents: list[Path] = field(default_factory=list)
    staged_here: bool = False  # this run made stage_root (a run refused before that must not delete it)

    def __post_init__(self):
        p = self.path
        if p.name in ("", ".", ".."):  # "--out ." : name it by its real path
            p = p.resolve()
        self.dest = p
        self.stage_root = p.parent / f".{p.name}{PARTIAL_TAG}{os.getpid()}"
        self.staged = self.stage_root if self.kind == "dir" else self.stage_root / p.name


class Staging:
    """The staged outputs of one run (see the module docstring); made by :func:`staged_outputs`."""

    def __init__(self, targets: list[_Target]):
        self.targets = targets

    def path(self, name: str) -> Path:
        """The path the job writes to instead of the output ``name``."""
        for t in self.targets:
            if t.name == name:
                return t.staged
        raise KeyError(name)

    def _pairs(self) -> list[tuple[str, str]]:
        pairs = []
        for t in self.targets:
            if t.kind == "dir":
                pairs += [(str(t.stage_root.resolve()), str(t.dest.resolve())), (str(t.stage_root), str(t.path))]
            else:
                pairs += [(str(t.staged.resolve()), str(t.dest.resolve())), (str(t.staged), str(t.path))]
                for root, parent in ((t.stage_root.resolve(), t.dest.resolve().parent), (t.stage_root, t.path.parent)):
                    pairs.append((str(root) + os.sep, "" if str(parent) == "." else str(parent) + os.sep))
        return sorted(pairs, key=lambda kv: -len(kv[0]))  # longest first

    def unstage(self, text: str) -> str:
        """``text`` with every staged path replaced by its destination's."""
        for a, b in self._pairs():
            text = text.replace(a, b)
        return text

    # -- commit / discard
    def _rewrite_texts(self) -> None:
        pairs = [(a.encode(), b.encode()) for a, b in self._pairs()]
        for t in self.targets:
            if not t.stage_root.is_dir():
                continue
            for f in t.stage_root.rglob("*"):
                if f.suffix.lower() not in TEXT_SUFFIXES or not f.is_file() or f.stat().st_size > MAX_REWRITE_BYTES:
                    continue
                data = f.read_bytes()
                new = data
                for a, b in pairs:
                    new = new.replace(a, b)
                if new != data:
                    tmp = f.with_name(f.name + ".unstage")
                    tmp.write_bytes(new)
                    os.replace(tmp, f)

    def commit(self) -> None:
        """Move every staged output into place (signals held back meanwhile)."""
        self._rewrite_texts()
        with signals_deferred():
            for t in self.targets:
                if not t.stage_root.exists():  # the job wrote nothing there (an optional output)
                    continue
                if t.kind == "dir":
                    if not t.dest.exists():
                        os.rename(t.stage_root, t.dest)
                        continue
                    if t.dest.is_dir() and not any(t.dest.iterdir()):
                        t.dest.rmdir()
                        os.rename(t.stage_root, t.dest)
                        continue
                    _move_entries(t.stage_root, t.dest)
                else:
                    _move_entries(t.stage_root, t.dest.parent)
                with contextlib.suppress(OSError):
                    t.stage_root.rmdir()

    def discard(self) -> None:
        """Delete everything staged, the locks and the folders made for it."""
        for t in self.targets:
            if t.staged_here:
                shutil.rmtree(t.stage_root, ignore_errors=True)
        self.release()
        for t in self.targets:
            for p in reversed(t.created_parents):
                with contextlib.suppress(OSError):
                    p.rmdir()

    def release(self) -> None:
        for t in self.targets:
            _release_target(t)


def _move_entries(src: Path, dst: Path) -> None:
    """Move every entry of ``src`` into ``dst``, replacing what is there under the same name."""
    for e in sorted(src.iterdir()):
        target = dst / e.name
        if target.is_dir() and not target.is_symlink():
            trash = dst / f".{e.name}{PARTIAL_TAG}old-{os.getpid()}"
            os.rename(target, trash)
            os.rename(e, target)
            shutil.rmtree(trash, ignore_errors=True)
        elif e.is_dir() and target.exists():
            target.unlink()
            os.rename(e, target)
        else:
            os.replace(e, target)


def _lock_path(t: _Target) -> Path:
    return t.dest.parent / f".{t.dest.name}{LOCK_SUFFIX}"


def _lock(t: _Target) -> None:
    import fcntl

    path = _lock_path(t)
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise InputError(f"{t.name} {t.path}: cannot write beside it ({e.strerror or e})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise InputError(f"{t.name} {t.path}: another facewarp run is writing it (lock {path}); wait for it to "
                             f"finish or choose another --{t.name}") from None
        try:  # the holder before us may have removed the file between our open and flock
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except OSError:
            same = False
        if same:
            t.lock_fd = fd
            return
        os.close(fd)


def _prepare(t: _Target) -> None:
    """Check the destination, make its parent folders, lock it and clear stale staging."""
    p, arg = t.dest, t.name
    if t.kind == "dir":
        if p.exists() and not p.is_dir():
            raise InputError(f"{arg} {t.path}: exists and is not a folder")
        missing = []
        q = p.parent
        while not q.exists() and q != q.parent:
            missing.append(q)
            q = q.parent
        if not q.is_dir():
            raise InputError(f"{arg} {t.path}: cannot create the folder ({q} is not a folder)")
        for m in reversed(missing):
            try:
                m.mkdir()
            except OSError as e:
                raise InputError(f"{arg} {t.path}: cannot create the folder {m} ({e.strerror or e})") from None
            t.created_parents.append(m)
    else:
        if p.is_dir():
            raise InputError(f"{arg} {t.path}: is a folder, expected a file name")
        if not p.parent.is_dir():
            raise InputError(f"{arg} {t.path}: folder {t.path.parent} does not exist")
    if not os.access(p.parent, os.W_OK | os.X_OK):
        raise InputError(f"{arg} {t.path}: the folder {p.parent} is not writable")
    if p.exists() and not os.access(p, os.W_OK):
        raise InputError(f"{arg} {t.path}: is read-only")
    _lock(t)
    for stale in p.parent.glob(f".{p.name}{PARTIAL_TAG}*"):  # left by a run that was killed (we hold the lock)
        if stale.is_dir():
            shutil.rmtree(stale, ignore_errors=True)
    try:
        t.stage_root.mkdir()
        t.staged_here = True
    except OSError as e:
        raise InputError(f"{arg} {t.path}: cannot write beside it ({e.strerror or e})") from None


@contextlib.contextmanager
def output_lock(name: str, path: os.PathLike | str) -> Iterator[Path]:
    """Hold the lock of the output ``path`` (the argument ``name``, e.g. ``"out"``) while the body runs.

    For an output a job writes in place rather than staged (``batch run --out DIR``, a folder
    continued from run to run): the same lock file ``.NAME.facewarp-lock`` beside it as
    :func:`staged_outputs` takes, so a second run on ``path`` (of any command) is refused with one
    line. The folders made to hold the lock file are removed again when the body raises and
    ``path`` was not made. Yields ``path`` as a :class:`~pathlib.Path`.

    Raises:
        InputError: ``path`` exists and is not a folder, its parent cannot be made or written, or
            another run holds the lock.
    """
    t = _Target(name, Path(path), "dir")
    if t.dest.exists() and not t.dest.is_dir():
        raise InputError(f"{name} {t.path}: exists and is not a folder")
    missing = []
    q = t.dest.parent
    while not q.exists() and q != q.parent:
        missing.append(q)
        q = q.parent
    if not q.is_dir():
        raise InputError(f"{name} {t.path}: cannot create the folder ({q} is not a folder)")
    for m in reversed(missing):
        try:
            m.mkdir()
        except OSError as e:
            for made in reversed(t.created_parents):
                with contextlib.suppress(OSError):
                    made.rmdir()
            raise InputError(f"{name} {t.path}: cannot create the folder {m} ({e.strerror or e})") from None
        t.created_parents.append(m)
    existed = t.dest.exists()
    try:
        if not os.access(t.dest.parent, os.W_OK | os.X_OK):
            raise InputError(f"{name} {t.path}: the folder {t.dest.parent} is not writable")
        _lock(t)
        yield Path(path)
    except BaseException:
        _release_target(t)
        if not existed and not t.dest.exists():
            for made in reversed(t.created_parents):
                with contextlib.suppress(OSError):
                    made.rmdir()
        raise
    _release_target(t)


def _release_target(t: _Target) -> None:
    """Release the lock of one output (remove its lock file, close it)."""
    if t.lock_fd is not None:
        with contextlib.suppress(OSError):
            os.unlink(_lock_path(t))
        with contextlib.suppress(OSError):
            os.close(t.lock_fd)
        t.lock_fd = None


@contextlib.contextmanager
def staged_outputs(outputs: list[tuple[str, os.PathLike | str, str]]) -> Iterator[Staging]:
    """Stage the outputs ``[(argument name, destination, "dir" | "file"), ...]`` for one run.

    Yields a :class:`Staging`; ``staging.path(name)`` is what the job must write to. When the
    body returns the staged files are moved into place; when it raises (an error, an
    :class:`Interrupted`) they are deleted and the exception propagates. Either way the locks
    are released.

    Raises:
        InputError: a destination of the wrong kind (a file where a folder is wanted or the
            other way round), a folder that cannot be made or written, or an output another
            run holds (its lock file is taken).
    """
    targets = []
    for name, path, kind in outputs:
        if kind not in ("dir", "file"):
            raise ValueError(f"kind must be 'dir' or 'file', got {kind!r}")
        if not str(path).strip():
            raise InputError(f"{name}: expected a {'folder' if kind == 'dir' else 'file'} path, got an empty one")
        targets.append(_Target(name, Path(path), kind))
    _check_apart(targets)
    staging = Staging(targets)
    try:
        for t in targets:
            _prepare(t)
        _active.append(staging)
        yield staging
        staging.commit()
    except BaseException:
        staging.discard()
        raise
    finally:
        if staging in _active:
            _active.remove(staging)
        staging.release()


_active: list[Staging] = []
"""The stagings of the runs in progress in this process (:func:`destination`)."""


def destination(path: os.PathLike | str) -> Path:
    """Where ``path`` ends up: a path inside a staged output of a run in progress is mapped to its
    destination (a job that gets ``.out.facewarp-partial-PID/x`` compares ``out/x`` with its
    inputs); any other path is returned as it is."""
    p = Path(path)
    for st in _active:
        for t in st.targets:
            root, dest = t.stage_root, (t.dest if t.kind == "dir" else t.dest.parent)
            for a in (root, root.absolute()):
                try:
                    rel = p.relative_to(a) if p.is_absolute() == a.is_absolute() else None
                except ValueError:
                    rel = None
                if rel is not None:
                    return dest / rel if str(rel) != "." else dest
    return p


def _check_apart(targets: list[_Target]) -> None:
    """Two outputs of one run must not be one path or one inside the other."""
    for i, a in enumerate(targets):
        for b in targets[i + 1:]:
            pa, pb = a.dest.absolute(), b.dest.absolute()
            if pa == pb or pa in pb.parents or pb in pa.parents:
                raise InputError(f"{b.name} {b.path}: is the same path as {a.name} {a.path} or inside it (or the other "
                                 f"way round); choose outputs apart")
