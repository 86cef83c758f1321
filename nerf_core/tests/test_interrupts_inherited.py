"""A parent may start nerf_core with SIGINT ignored or blocked (both survive exec): the CLI must still
stop on Ctrl-C or the add-on's Cancel, so that the trainer saves its checkpoint."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import signal
from nerf_core.utils.interrupts import honour_interrupts
blocked = lambda: signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])
before = (signal.getsignal(signal.SIGINT) == signal.SIG_IGN, blocked())
honour_interrupts()
after = (signal.getsignal(signal.SIGINT) is signal.default_int_handler, blocked())
print(before, after)
"""


def _hostile_parent():
    """In the child before exec: SIGINT ignored and SIGINT/SIGTERM blocked, as a parent may leave them."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})


@pytest.mark.skipif(os.name != "posix", reason="signal masks are POSIX")
def test_ignored_and_blocked_interrupts_are_honoured_again():
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, timeout=60,
                         preexec_fn=_hostile_parent)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["(True,", "True)", "(True,", "False)"], out.stdout


HUP_PROBE = """
import signal
from nerf_core.utils.interrupts import honour_interrupts
blocked = lambda: signal.SIGHUP in signal.pthread_sigmask(signal.SIG_BLOCK, [])
before = blocked()
honour_interrupts()
print(before, blocked(), signal.getsignal(signal.SIGHUP) == signal.SIG_IGN)
"""


@pytest.mark.skipif(os.name != "posix", reason="signal masks are POSIX")
@pytest.mark.parametrize("ignored", [False, True])
def test_a_blocked_sighup_is_unblocked_and_an_ignored_one_stays_ignored(ignored):
    def parent():  # set both ways: the test runner itself may run under nohup
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGHUP})
        # ignored is what nohup does: the run must then survive the terminal closing
        signal.signal(signal.SIGHUP, signal.SIG_IGN if ignored else signal.SIG_DFL)

    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    out = subprocess.run([sys.executable, "-c", HUP_PROBE], capture_output=True, text=True, env=env, timeout=60,
                         preexec_fn=parent)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "False", str(ignored)], out.stdout
