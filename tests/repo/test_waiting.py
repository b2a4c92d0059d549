"""The tests' one wait (tests/waiting.py): an exit fails it only if what the process sent before
does not make the condition true; a timeout always fails it."""
import subprocess
import sys

import pytest

from waiting import handshake, spin_until


def _ended(code: int) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", f"import sys; sys.stderr.write('bye'); sys.exit({code})"],
                            stderr=subprocess.PIPE)
    proc.wait()
    return proc


def test_an_exit_counts_only_after_what_was_queued_is_read():
    queued = [1, 2, 3]                  # what the ended process sent: still to be read
    seen = []
    spin_until(lambda: queued and seen.append(queued.pop(0)), lambda: len(seen) == 3, 5, [_ended(0)])
    assert seen == [1, 2, 3]


def test_an_exit_whose_messages_do_not_satisfy_the_wait_fails_with_its_stderr():
    with pytest.raises(pytest.fail.Exception, match=r"(?s)the tick.*exited with 3.*bye"):
        spin_until(lambda: None, lambda: False, 30, [_ended(3)], "the tick")


def test_a_timeout_fails():
    with pytest.raises(pytest.fail.Exception, match="not within 0.05 s"):
        spin_until(lambda: None, lambda: False, 0.05)


class _Pub:
    topic = "/t"

    def __init__(self, subscribed_after: int):
        self.calls, self.after = 0, subscribed_after

    def wait_for_subscribers(self, n, timeout_s):
        self.calls += 1
        return self.calls > self.after


def test_a_handshake_waits_for_the_subscription_and_fails_when_the_reader_exits_without_it():
    pub = _Pub(3)
    handshake(pub, 5)
    assert pub.calls == 4
    with pytest.raises(pytest.fail.Exception, match=r"(?s)subscriber\(s\) of /t.*exited with 2"):
        handshake(_Pub(10 ** 9), 30, [_ended(2)])
