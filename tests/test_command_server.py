"""The tests' command server (tests/command_server.py): a test that gives up waiting for a command must not hand its
late reply to the next test. It did: a slow test's pytest-timeout shifted every later reply by one, and twelve
slow tests failed with their predecessors' output."""

from __future__ import annotations

import signal

import pytest
from conftest import command_server, run_cli


class GaveUpError(Exception):
    pass


@pytest.mark.slow  # 20 s, most of it the new server's imports; what it guards shows only after a test's timeout
def test_a_command_given_up_on_ends_with_its_server_and_the_next_one_gets_its_own_output(tmp_path):
    server = command_server()
    if server is None:
        pytest.skip("the tests run without the command server (ADADEMO_TESTS_NO_FORK=1)")

    def give_up(*_):
        raise GaveUpError  # as pytest-timeout's signal method fails a test: an exception in the waiting thread

    previous = signal.signal(signal.SIGALRM, give_up)
    signal.setitimer(signal.ITIMER_REAL, 1.0)
    try:
        with pytest.raises(GaveUpError):  # a collection of 10 demonstrations: longer than a second
            run_cli(
                "adademo-collect",
                "--suite.tasks=reach-v3",
                "--episodes_per_task=10",
                "--dataset.repo_id=local/slow",
                f"--dataset.root={tmp_path / 'slow'}",
            )
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert server.proc.poll() is not None  # ended, with the command it ran (its process group)
    assert "--strategy.type" in run_cli("adademo-expand", "--help").stdout  # not the collection's output
    assert command_server() is not server
