"""Ctrl-C while a command runs: exit code 130 and one line, wherever in a library the signal lands.

Python runs a signal's handler at the next bytecode of the main thread. When that bytecode belongs to a Python
function that a C++ extension called, the extension decides what becomes of the ``KeyboardInterrupt``:

* Dr.Jit's conversion of a torch tensor (``TensorXf(tensor)``) calls ``Tensor.__dlpack__`` and, when that raises,
  clears the error and converts another way: the interrupt is lost and the command runs to its end (exit code 0);
* Dr.Jit's kernel recording (``dr.freeze``) and its traversal of a frozen function's arguments raise a
  ``RuntimeError`` from it (``record(): error encountered while recording a frozen function``): two tracebacks
  and exit code 1;
* any other Python callback of Dr.Jit, Mitsuba or PyTorch may do either.

What holds whatever a library does with it, while :func:`install` has made :func:`on_sigint` the handler (the
``mi-svbrdf`` process, from the moment its command starts):

* the handler records the first Ctrl-C (:func:`requested`) before it raises, and does not raise while an
  exception is being handled (an ``except`` or ``finally`` block, a context manager's exit: a file half cleaned
  up, a line half printed);
* until the command's work is over (:func:`stop_raising`), a watchdog thread raises the interrupt again every
  :data:`RETRY_S` seconds: an interrupt that a library lost, or that arrived while an exception was handled,
  stops the command at most that much later;
* an exception that a Ctrl-C caused (a ``KeyboardInterrupt`` in its ``__cause__``/``__context__`` chain), or any
  exception that ends a command after a Ctrl-C, is the interrupt (:func:`is_interruption`): one line, exit code
  130 (:func:`mi_svbrdf.cli.common.run`); a command that outran a lost interrupt is stopped by
  :func:`stop_raising` before it reports success;
* once the outcome is decided (:func:`settle`), Ctrl-C gets its default action: the process ends at once, as
  killed by SIGINT (a shell reports exit code 130); a Ctrl-C recorded while the outcome was being reported makes
  it 130 with one more line.

Elsewhere (Python code calling :func:`mi_svbrdf.cli.main`, the tests), the handler is left as it is and only
:func:`is_interruption` applies.
"""
from __future__ import annotations

import _thread
import signal
import sys
import threading
import time
from dataclasses import dataclass
from types import FrameType

__all__ = ["RETRY_S", "install", "interruption_detail", "is_interruption", "on_sigint", "requested", "settle",
           "stop_raising"]

#: Seconds between the watchdog's raises of an interrupt the command has not stopped for yet.
RETRY_S = 0.5


@dataclass
class _State:
    """The command's Ctrl-C state in this process."""

    installed: bool = False  #: :func:`on_sigint` is the SIGINT handler (the ``mi-svbrdf`` process)
    at: float | None = None  #: ``time.monotonic()`` of the first Ctrl-C, None before one
    raising: bool = True  #: the command works: Ctrl-C raises ``KeyboardInterrupt`` (else it is only recorded)
    watchdog: threading.Thread | None = None


_STATE = _State()


def install() -> None:
    """Make :func:`on_sigint` the SIGINT handler for the command that starts (in the main thread)."""
    _STATE.at, _STATE.raising, _STATE.watchdog = None, True, None
    signal.signal(signal.SIGINT, on_sigint)
    _STATE.installed = True


def requested() -> bool:
    """Whether Ctrl-C came since :func:`install` (whatever became of its ``KeyboardInterrupt``)."""
    return _STATE.at is not None


def on_sigint(signum: int, frame: FrameType | None) -> None:
    """The SIGINT handler while a command runs: record the Ctrl-C; raise ``KeyboardInterrupt`` unless the work is
    over or an exception is being handled (the watchdog, started by the first Ctrl-C, raises it again later)."""
    first = _STATE.at is None
    if first:
        _STATE.at = time.monotonic()
    if not _STATE.raising:
        return
    if first:
        _STATE.watchdog = threading.Thread(target=_watch, name="mi-svbrdf Ctrl-C watchdog", daemon=True)
        _STATE.watchdog.start()
    if sys.exc_info()[1] is not None:
        return
    raise KeyboardInterrupt


def _watch() -> None:
    """While the command still works after a Ctrl-C, deliver SIGINT to the main thread every :data:`RETRY_S` (a
    signal, where the platform can send one to a thread: it also ends a wait in a system call, ``time.sleep``)."""
    main = threading.main_thread().ident
    while True:
        time.sleep(RETRY_S)
        if not _STATE.raising:
            return
        if signal.getsignal(signal.SIGINT) is not on_sigint:  # a handler a command installed for itself
            continue
        if hasattr(signal, "pthread_kill") and main is not None:
            signal.pthread_kill(main, signal.SIGINT)
        else:
            _thread.interrupt_main(signal.SIGINT)


def stop_raising(code: int | None = None) -> None:
    """The command's work is over (``code``: its exit code), or its interrupt is being answered (None): from now on
    Ctrl-C is only recorded, and the watchdog stops.

    Raises:
        KeyboardInterrupt: Ctrl-C came and ``code`` is not 130 (the command ran on: a library lost the interrupt).
    """
    _STATE.raising = False
    if code is not None and code != 130 and requested():
        raise KeyboardInterrupt


def settle(code: int, late_line: str) -> int:
    """The command's exit code, once its outcome has been reported: 130 (with ``late_line`` printed to stderr)
    when Ctrl-C came while it was reported. From here on Ctrl-C ends the process at once (its default action,
    a shell's exit code 130), where :func:`install` made the command's handler the process's."""
    if _STATE.installed:
        sys.stdout.flush()
        sys.stderr.flush()
        signal.signal(signal.SIGINT, signal.SIG_DFL)  # runs the handler of a Ctrl-C still pending first: recorded
        _STATE.installed = False
    if code != 130 and requested():
        print(late_line, file=sys.stderr, flush=True)
        return 130
    return code


def _chain(exc: BaseException) -> list[BaseException]:
    """``exc`` and the exceptions it was raised from or while handling (``__cause__``, ``__context__``)."""
    seen: list[BaseException] = []
    todo = [exc]
    while todo:
        e = todo.pop()
        if any(e is s for s in seen):
            continue
        seen.append(e)
        todo += [c for c in (e.__cause__, e.__context__) if c is not None]
    return seen


def is_interruption(exc: BaseException) -> bool:
    """Whether ``exc`` ends the command as Ctrl-C does: a ``KeyboardInterrupt``, an exception raised from or while
    handling one (a library's ``RuntimeError`` around it), or any exception after Ctrl-C came (:func:`requested`).

    Examples:
        >>> try:
        ...     try:
        ...         raise KeyboardInterrupt
        ...     except KeyboardInterrupt as exc:
        ...         raise RuntimeError("record(): error encountered while recording a function") from exc
        ... except RuntimeError as err:
        ...     is_interruption(err)
        True
        >>> is_interruption(ValueError("bad input"))
        False
    """
    return requested() or any(isinstance(e, KeyboardInterrupt) for e in _chain(exc))


def interruption_detail(exc: BaseException) -> str:
    """What the command said when it stopped: the message of the ``KeyboardInterrupt`` in ``exc``'s chain (a
    command raises one with a message, e.g. where its checkpoint is), "" where it has none (a plain Ctrl-C).

    Examples:
        >>> interruption_detail(KeyboardInterrupt("stopped at step 3"))
        'stopped at step 3'
        >>> interruption_detail(RuntimeError("record(): error"))
        ''
    """
    for e in _chain(exc):
        if isinstance(e, KeyboardInterrupt) and str(e):
            return " ".join(str(e).split())
    return ""
