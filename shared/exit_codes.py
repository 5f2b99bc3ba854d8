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
    return EXIT_INTERRUPTED
