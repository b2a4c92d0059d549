"""What every device emulator shares: open its endpoint (a socket, a pty), serve it on a daemon
thread until stop(), then close the endpoint; `with emulator:` does start() and stop().

A subclass defines `_open()` (bind or create the endpoint; raises when it cannot), `_serve()` (the
thread's loop: runs until `self._stop` is set) and `_close()` (closes what `_open` made; called
after the thread has ended, so the loop never sees a closed endpoint).
"""
from __future__ import annotations

import threading

__all__ = ["ThreadedEmulator"]


class ThreadedEmulator:
    """The start/stop and context-manager logic of an emulator served by one thread."""

    THREAD_NAME = "emulator"
    JOIN_TIMEOUT_S: float | None = None     # how long stop() waits for the thread (None: until it ends)

    def __init__(self) -> None:
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def _open(self) -> None:
        raise NotImplementedError

    def _serve(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def start(self):
        """Opens the endpoint and serves it on a daemon thread; returns self."""
        self._open()
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name=self.THREAD_NAME, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Ends the thread, then closes the endpoint."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(self.JOIN_TIMEOUT_S)
            self._thread = None
        self._close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
