"""How SIGINT (Ctrl-C) and SIGTERM reach warprt's work, and when they wait.

Work that must not be cut in two holds the signals that arrive while it runs, in a
:class:`Deferred` block: a render's passes (``render._CtrlC``: the render then returns the samples
it has), the frames of a sequence, and the writing of an image (:func:`warprt.image.save_image`:
a file is finished before the interrupt is delivered; a second signal during the same write
abandons it, leaving any older file in place). Blocks nest: a signal is seen by every open block,
and is held when all of them hold it.

As a library warprt touches only Python's default SIGINT handler, and only while such a block
runs in the main thread (a host application's own handler, or an ignored SIGINT, is left alone;
SIGTERM is never touched): when the outermost block ends with a signal held, it raises
``KeyboardInterrupt`` there, so a script still stops on Ctrl-C, after the work in hand is safe.

The command line (:func:`program`) handles SIGTERM as it handles SIGINT, for its whole run:
outside a block either raises ``KeyboardInterrupt`` (the CLI prints one line and exits 128 + the
signal's number: 130 for SIGINT, 143 for SIGTERM), inside one it is held like a Ctrl-C.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Callable

_listeners: list["Deferred"] = []  # the open blocks, innermost last (main thread only)
_program: "Program | None" = None  # the command line's run, while its handlers are installed


class Program:
    """The signals a command-line run received (``received``: signal numbers, in order)."""

    def __init__(self):
        self.received: list[int] = []

    @property
    def first(self) -> int | None:
        return self.received[0] if self.received else None

    def exit_code(self) -> int:
        """128 + the first signal's number (130 for SIGINT, 143 for SIGTERM); 130 when the
        interrupt came without a signal (``KeyboardInterrupt`` raised by other means)."""
        return 128 + (self.first or signal.SIGINT)


def in_program() -> bool:
    """Whether the command line's handlers are installed (an interrupt ends the process)."""
    return _program is not None


def _dispatch(signum, frame) -> None:
    """The handler of SIGINT (and, in the command line, SIGTERM) while warprt holds it: every open
    block sees the signal; it is held when all of them hold it, else ``KeyboardInterrupt``."""
    if _program is not None:
        _program.received.append(signum)
    hold = bool(_listeners)
    for block in reversed(list(_listeners)):
        hold = block._notify(signum) and hold
    if not hold:
        raise KeyboardInterrupt


def signal_name(signum: int | None) -> str:
    try:
        return signal.Signals(signum).name
    except (TypeError, ValueError):
        return "SIGINT"


class Deferred:
    """A block during which SIGINT (and SIGTERM in the command line) is held instead of raising.

    ``signals`` lists the signals seen (``pressed`` / ``is_set()``: any, so the block can be
    handed to ``Renderer.render(stop=...)``). ``abandon_on`` (a count, or None to hold every
    signal): the signal that many arrived in the block is not held but raises
    ``KeyboardInterrupt`` at once. ``on_first(signum)`` is called on the first one (e.g. to say
    what is being finished). ``deliver``: when the block is the outermost over Python's default
    handler (a library call, not the command line), raise the held ``KeyboardInterrupt`` as it
    ends (else the caller reads ``pressed``, as a render does). Active only in the main thread,
    over Python's default SIGINT handler or the command line's; elsewhere the block does nothing
    (``active`` is False)."""

    def __init__(self, abandon_on: int | None = None, on_first: Callable[[int], None] | None = None,
                 deliver: bool = False):
        self.signals: list[int] = []
        self.abandon_on = abandon_on
        self.on_first = on_first
        self.deliver = deliver
        self.active = False
        self._previous = None  # the SIGINT handler this block replaced (outermost block only)

    @property
    def pressed(self) -> bool:
        return bool(self.signals)

    def is_set(self) -> bool:
        return self.pressed

    def _notify(self, signum: int) -> bool:
        self.signals.append(signum)
        if len(self.signals) == 1 and self.on_first is not None:
            try:
                self.on_first(signum)
            except Exception:  # a message that cannot be printed must not lose the work
                pass
        return self.abandon_on is None or len(self.signals) < self.abandon_on

    def __enter__(self) -> "Deferred":
        if threading.current_thread() is not threading.main_thread():
            return self
        try:
            current = signal.getsignal(signal.SIGINT)
            if current is signal.default_int_handler:
                self._previous = signal.signal(signal.SIGINT, _dispatch)
            elif current is not _dispatch:
                return self  # the host application's handler (or SIG_IGN): left alone
        except (ValueError, OSError):  # not the main interpreter
            return self
        _listeners.append(self)
        self.active = True
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if not self.active:
            return False
        self.active = False
        if self in _listeners:
            _listeners.remove(self)
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
            self._previous = None
            # the outermost block of a library call: deliver the held interrupt now that the work
            # is safe (not over an exception already on its way out)
            if self.signals and exc_type is None and self.deliver:
                raise KeyboardInterrupt
        return False


@contextmanager
def program(ignore_after: bool = False):
    """The command line's signal handling for the ``with`` block: SIGINT and SIGTERM both go to
    warprt's handler (see the module docstring); yields the :class:`Program` recording them. The
    previous handlers come back at the end, or, with ``ignore_after`` (the process exits next),
    both signals are ignored from then on, so that nothing of the exit can be interrupted into a
    traceback."""
    global _program
    run = Program()
    if threading.current_thread() is not threading.main_thread():
        yield run
        return
    previous = {}
    for s in (signal.SIGINT, signal.SIGTERM):
        try:
            previous[s] = signal.signal(s, _dispatch)
        except (ValueError, OSError):
            pass
    outer, _program = _program, run
    try:
        yield run
    finally:
        _program = outer
        for s, handler in previous.items():
            signal.signal(s, signal.SIG_IGN if ignore_after else handler)
