"""The ``qhsm`` command's exit statuses beyond 0 (one place: the core and the service commands
share them)."""

import signal
import threading

#: An error was reported (a message on stderr, no traceback).
EXIT_FAILED = 1
#: Ctrl-C: as a shell reports a process ended by SIGINT (128 + 2).
EXIT_INTERRUPTED = 130
#: stdout's reader went away (``qhsm estimate ... | head``): as if killed by SIGPIPE (128 + 13).
EXIT_BROKEN_PIPE = 141


def interrupted() -> int:
    """:data:`EXIT_INTERRUPTED`, once Ctrl-C has been answered (the message printed): from here
    on SIGINT is ignored, so a second Ctrl-C (or a late one of the same keypress reaching the
    interpreter as it exits) cannot turn the status into a death by SIGINT and a traceback."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    _forget_interrupt_in_exec()
    return EXIT_INTERRUPTED


def _forget_interrupt_in_exec() -> None:
    """CPython 3.11-3.13 remember a KeyboardInterrupt raised inside code that ``exec`` / ``eval``
    run from a string (a dataclass's generated ``__init__`` while a module is imported lazily, say)
    even once it was caught, and ``python -m`` then ends the process by SIGINT instead of with the
    status returned (a -2 instead of 130 once in a few Ctrl-Cs of ``python -m shared.cli submit
    --wait``). Running an empty string resets that flag (CPython's ``run_eval_code_obj``); 3.14
    sets it only for an interrupt nobody caught (python/cpython#128130), where this is a no-op."""
    exec("")  # a constant empty string, run for that side effect
