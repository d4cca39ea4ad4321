"""A step's outputs go out whole or not at all, whatever signal ends the node.

Where a signal lands with rclpy's own handlers (Jazzy): on
SIGINT or SIGTERM rclpy's C handler shuts the context down from its signal
thread at once, so every publish after that fails ("publisher's context is
invalid"); on SIGINT it also chains to Python's handler, which raises
KeyboardInterrupt in the main thread, the node's step thread (it spins the
executor), at the next bytecode. Either can land between two publishes of one
step: its energy was out, live and in the node's bag, but not its wrench,
points or applied tool, so the bag held one energy message more than
replayable steps.

So :func:`~tissue_sim_ros.ros.node.process.main` initialises rclpy without its
signal handlers and installs :class:`SignalShutdown`:

* a step publishes inside the node's :class:`OutputGate`; the gate is checked
  before the step's first message (closed: nothing of the step goes out) and
  held until its last one is out;
* the signal's C-level handler only writes its number to a pipe
  (``signal.set_wakeup_fd``); a watcher thread reads it, closes the gate (so
  it waits for a step being published) and then shuts the context down, which
  wakes the executor as rclpy's handler does (``spin`` ends with
  ExternalShutdownException);
* SIGINT still raises KeyboardInterrupt in the main thread (so it ends a long
  start-up at once, as before), except while the main thread publishes a step:
  then it is raised when the step's last message is out.
"""
from __future__ import annotations

import contextlib
import os
import signal
import threading
from typing import Any

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class OutputGate:
    """Held while a step publishes; once closed (the node is stopping) no step publishes any more.

    Use::

        with node.output_gate as open_:
            if open_:
                ...  # publish the whole step
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.closed = False
        self.publishing_thread: int | None = None
        """The thread publishing a step now (its ident), else None."""
        self.interrupt_pending = False
        """A SIGINT came while the main thread published: KeyboardInterrupt is raised when the step is out."""

    def __enter__(self) -> bool:
        # marked first: from here on a SIGINT waits for the step's end (a signal before it raises at once,
        # before anything of the step is out)
        self.publishing_thread = threading.get_ident()
        self._lock.acquire()
        return not self.closed

    def __exit__(self, *exc: object) -> None:
        self._lock.release()
        self.publishing_thread = None
        if self.interrupt_pending and threading.current_thread() is threading.main_thread():
            self.interrupt_pending = False
            raise KeyboardInterrupt

    def close(self) -> None:
        """No step publishes from now on; waits for the one being published."""
        with self._lock:
            self.closed = True


class SignalShutdown:
    """SIGINT and SIGTERM end the node between two steps' outputs, never inside one (module docstring).

    Parameters
    ----------
    context : rclpy.context.Context
        Initialised without rclpy's signal handlers (``SignalHandlerOptions.NO``); shut down on a signal.

    Install from the main thread; :attr:`gate` is the node's :class:`OutputGate` once the node exists (before,
    a signal only shuts the context down, and SIGINT raises KeyboardInterrupt).
    """

    def __init__(self, context: Any) -> None:
        self.context = context
        self.gate: OutputGate | None = None
        self.signals: list[int] = []
        """The signals received, in order."""
        self._saved = {sig: signal.getsignal(sig) for sig in SIGNALS}
        self._read_fd, self._write_fd = os.pipe()
        os.set_blocking(self._write_fd, False)
        for sig in SIGNALS:
            signal.signal(sig, self._on_signal)
        self._saved_wakeup_fd = signal.set_wakeup_fd(self._write_fd, warn_on_full_buffer=False)
        self._thread = threading.Thread(target=self._watch, name="signal_shutdown", daemon=True)
        self._thread.start()

    def _on_signal(self, signum: int, _frame: Any) -> None:
        """Python's handler (main thread, between bytecodes): SIGINT raises KeyboardInterrupt unless a step is
        being published on this thread (then the gate raises it at the step's end)."""
        if signum != signal.SIGINT:
            return  # SIGTERM: the watcher shuts the context down
        gate = self.gate
        if gate is not None and gate.publishing_thread == threading.get_ident():
            gate.interrupt_pending = True
            return
        raise KeyboardInterrupt

    def _watch(self) -> None:
        while True:
            try:
                data = os.read(self._read_fd, 64)
            except OSError:
                return
            if not data or 0 in data:  # closed, or uninstall's 0: no signal has number 0
                return
            self.signals.extend(data)
            gate = self.gate
            if gate is not None:
                gate.close()  # waits for a step being published
            with contextlib.suppress(Exception):  # already shut down (main's finally got there first)
                self.context.try_shutdown()

    def uninstall(self) -> None:
        """Put the previous handlers back and end the watcher thread (main thread, after the node is gone)."""
        signal.set_wakeup_fd(self._saved_wakeup_fd)
        for sig, handler in self._saved.items():
            if handler is not None:
                signal.signal(sig, handler)
        with contextlib.suppress(OSError):
            os.write(self._write_fd, b"\0")
        self._thread.join(timeout=2.0)
        for fd in (self._read_fd, self._write_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
