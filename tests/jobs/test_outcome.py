"""spm_data.jobs.outcome: what local and Ray executors share: outcomes, error text, and the first
Ctrl-C turned into a flag."""

import os
import signal
import sys
import threading

import pytest

from spm_data.errors import ShardError, SpmError
from spm_data.jobs.outcome import JobOutcome, deferred_interrupt, error_text, is_blender_script_dir, probe_job


def test_an_outcome_is_one_attempt_without_error_by_default():
    outcome = JobOutcome(job=("a", 1))
    assert (outcome.job, outcome.result, outcome.error, outcome.attempts) == (("a", 1), None, None, 1)


def test_error_text_gives_our_message_alone_and_names_other_exceptions():
    assert error_text(SpmError("cup-00001.h5: bad")) == "cup-00001.h5: bad"
    assert error_text(ShardError("shard not found: x.h5")) == "shard not found: x.h5"
    assert error_text(ValueError("math domain error")) == "ValueError: math domain error"
    assert error_text(KeyError("rgb")) == "KeyError: 'rgb'"


@pytest.mark.parametrize("path, expected", [
    ("/opt/blender/5.0/scripts/modules", True), ("C:\\Blender\\5.0\\scripts\\bpy", True),
    ("/usr/lib/python3/site-packages", False), ("/home/me/scripts", False), ("/opt/blender/5.0/python", False),
])
def test_is_blender_script_dir(path, expected):
    assert is_blender_script_dir(path) is expected


def test_probe_job_reports_and_says_which_process_ran_it():
    reported = []
    assert probe_job(7, reported.append) == {"job": 7, "pid": os.getpid()}
    assert reported == [1]


@pytest.fixture
def default_sigint():
    """SIGINT handled as Python does by default (KeyboardInterrupt), restored after."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def test_the_first_ctrl_c_sets_the_flag_and_the_second_interrupts(default_sigint):
    with deferred_interrupt() as stop:
        assert not stop.is_set() and signal.getsignal(signal.SIGINT) is not signal.default_int_handler
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.wait(timeout=10)                   # a flag, no KeyboardInterrupt
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            threading.Event().wait(timeout=10)         # the second one raises at once
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler   # restored


def test_a_thread_or_a_caller_with_its_own_handler_keeps_its_handler(default_sigint):
    seen = []

    def in_thread():
        with deferred_interrupt() as stop:
            seen.append((stop.is_set(), signal.getsignal(signal.SIGINT)))

    thread = threading.Thread(target=in_thread)
    thread.start()
    thread.join()
    assert seen == [(False, signal.default_int_handler)]

    def mine(signum, frame):
        pass

    signal.signal(signal.SIGINT, mine)
    with deferred_interrupt() as stop:
        assert signal.getsignal(signal.SIGINT) is mine and not stop.is_set()
    assert signal.getsignal(signal.SIGINT) is mine


def test_a_signal_landing_in_a_finaliser_is_recorded_not_raised_there():
    """A KeyboardInterrupt raised inside __del__ is printed as "Exception ignored" and lost;
    there the signal is only recorded, and the next deferred run stops at once."""
    from spm_data.jobs import outcome

    class Holder:
        def __del__(self):
            outcome._raise_interrupt(signal.SIGTERM, sys._getframe())

    signal.signal(signal.SIGINT, signal.default_int_handler)   # Python's own handlers, as a command starts with
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    outcome.signals_for_work()
    try:
        Holder()   # collected at once: __del__ runs, nothing raised
        assert outcome.received() == signal.SIGTERM and outcome.exit_status() == 143
        with deferred_interrupt() as stop:
            assert stop.is_set()
        with pytest.raises(KeyboardInterrupt):
            outcome._raise_interrupt(signal.SIGINT, sys._getframe())
    finally:
        outcome.signals_for_work()
        outcome.end_of_command()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def test_a_signal_landing_in_a_weakref_callback_is_recorded_not_raised_there():
    """Issue 47: SIGTERM 1 s into `spm train` landed in WeakValueDictionary's `remove` callback;
    the KeyboardInterrupt raised there was printed as "Exception ignored in: <function
    WeakValueDictionary.__init__.<locals>.remove …>" with a traceback, and lost. The key's
    __hash__, which that callback calls, stands in for where the signal lands."""
    import weakref

    from spm_data.jobs import outcome

    handler, unraisable = [None], []

    class Key:
        def __hash__(self):
            if handler[0] is not None:
                handler[0](signal.SIGTERM, sys._getframe())
            return 1

    class Value:
        pass

    def free_a_value():   # the dictionary's remove callback runs, and hashes the key
        table, value = weakref.WeakValueDictionary(), Value()
        table[Key()] = value
        del value
        assert len(table) == 0

    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    outcome.signals_for_work()
    hook, sys.unraisablehook = sys.unraisablehook, unraisable.append
    try:
        handler[0] = outcome._raise_interrupt
        free_a_value()
        assert unraisable == [] and outcome.received() == signal.SIGTERM and outcome.exit_status() == 143
        with pytest.raises(KeyboardInterrupt):
            with deferred_interrupt() as stop:
                assert stop.is_set()   # the next safe point acts on it
                handler[0] = signal.getsignal(signal.SIGTERM)
                free_a_value()         # a second signal, in a callback again: recorded
                assert unraisable == []
                handler[0](signal.SIGTERM, sys._getframe())   # in plain code: raised at once
        handler[0] = None
        with pytest.raises(KeyboardInterrupt):
            outcome._raise_interrupt(signal.SIGINT, sys._getframe())   # outside a callback: raised as before
    finally:
        sys.unraisablehook = hook
        outcome.signals_for_work()
        outcome.end_of_command()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
