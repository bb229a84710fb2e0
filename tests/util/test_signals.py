"""SIGTERM as Ctrl-C within the block, the previous handler back afterwards, nothing touched off the
main thread."""

from __future__ import annotations

import os
import signal
import threading

import pytest

from bimgame.util.signals import sigterm_as_interrupt


@pytest.fixture
def custom_sigterm_handler():
    """A recording SIGTERM handler installed for the test; the original one is restored after."""
    received: list[int] = []

    def handler(signum, frame):
        received.append(signum)

    original = signal.signal(signal.SIGTERM, handler)
    try:
        yield handler, received
    finally:
        signal.signal(signal.SIGTERM, original)


def test_sigterm_raises_keyboard_interrupt_inside_the_block(custom_sigterm_handler):
    handler, received = custom_sigterm_handler
    reached_after_kill = False
    with pytest.raises(KeyboardInterrupt):
        with sigterm_as_interrupt():
            assert signal.getsignal(signal.SIGTERM) is not handler
            os.kill(os.getpid(), signal.SIGTERM)
            reached_after_kill = True  # pragma: no cover - the signal interrupts before this line
    assert not reached_after_kill
    assert received == []  # the custom handler did not see it
    assert signal.getsignal(signal.SIGTERM) is handler


def test_previous_handler_is_restored_after_a_normal_exit(custom_sigterm_handler):
    handler, received = custom_sigterm_handler
    with sigterm_as_interrupt():
        pass
    assert signal.getsignal(signal.SIGTERM) is handler
    os.kill(os.getpid(), signal.SIGTERM)  # goes to the custom handler again, no KeyboardInterrupt
    assert received == [signal.SIGTERM]


def test_previous_handler_is_restored_after_another_exception(custom_sigterm_handler):
    handler, _ = custom_sigterm_handler
    with pytest.raises(RuntimeError, match="boom"):
        with sigterm_as_interrupt():
            raise RuntimeError("boom")
    assert signal.getsignal(signal.SIGTERM) is handler


def test_nested_blocks_restore_in_order(custom_sigterm_handler):
    handler, _ = custom_sigterm_handler
    with sigterm_as_interrupt():
        inner_previous = signal.getsignal(signal.SIGTERM)
        with sigterm_as_interrupt():
            pass
        assert signal.getsignal(signal.SIGTERM) is inner_previous
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
    assert signal.getsignal(signal.SIGTERM) is handler


def test_other_threads_run_the_block_without_touching_handlers(custom_sigterm_handler):
    handler, received = custom_sigterm_handler
    outcome: dict[str, object] = {}

    def work():
        try:
            with sigterm_as_interrupt():
                outcome["inside"] = signal.getsignal(signal.SIGTERM)
                outcome["ran"] = True
        except BaseException as error:  # pragma: no cover - a failure is reported below
            outcome["error"] = error

    thread = threading.Thread(target=work)
    thread.start()
    thread.join(timeout=10)
    assert not thread.is_alive()
    assert "error" not in outcome, outcome.get("error")
    assert outcome["ran"] is True
    assert outcome["inside"] is handler
    assert signal.getsignal(signal.SIGTERM) is handler
