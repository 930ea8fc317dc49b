"""The launcher's supervisor (restart with back-off) on a tiny stand-in process: it restarts a
killed process, and once :meth:`Stack.stop` is called it returns promptly and starts nothing
more (issue 11, item 4: the fault runs depend on both)."""

from __future__ import annotations

import signal
import socket
import sys
import threading
import time

import pytest
from sqmanip.launch import Proc, Stack, settings_on_free_ports

pytestmark = pytest.mark.integration

SLEEPER = [sys.executable, "-c", "import time; time.sleep(120)"]


@pytest.fixture
def listener():
    """A listening socket: the stand-in's ``tcp:`` readiness check passes at once."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


def _stack(port: int) -> Stack:
    stack = Stack(settings_on_free_ports(), (), gateway=False, zenoh=False, restart=True)
    stack.procs.append(Proc("sleeper", list(SLEEPER), f"tcp:127.0.0.1:{port}"))
    return stack


def test_killed_process_is_restarted_and_stop_ends_supervision(listener) -> None:
    stack = _stack(listener).start(30)
    proc = stack._proc("sleeper")
    first_pid = proc.popen.pid
    codes: list[int] = []
    thread = threading.Thread(target=lambda: codes.append(stack.supervise(poll_s=0.05)))
    thread.start()
    try:
        stack.kill("sleeper", signal.SIGKILL)
        deadline = time.monotonic() + 15  # back-off 1 s, then a fresh interpreter
        while time.monotonic() < deadline and not (proc.restarts == 1 and proc.alive()):
            time.sleep(0.05)
        assert proc.restarts == 1 and proc.alive() and proc.popen.pid != first_pid
    finally:
        t0 = time.monotonic()
        stack.stop(grace=2)
        thread.join(5)
    assert not thread.is_alive() and codes == [0]
    assert time.monotonic() - t0 < 5
    assert not proc.alive()


def test_no_restart_after_stop(listener) -> None:
    """A process that dies while the stack stops is not started again behind stop's back."""
    stack = _stack(listener).start(30)
    proc = stack._proc("sleeper")
    thread = threading.Thread(target=stack.supervise, kwargs={"poll_s": 0.05})
    thread.start()
    stack.kill("sleeper", signal.SIGKILL)
    proc.popen.wait(5)
    stack.stop(grace=2)  # within the 1 s back-off
    thread.join(5)
    assert not thread.is_alive()
    time.sleep(1.5)  # past the back-off: still nothing started
    assert proc.restarts == 0 and not proc.alive()
