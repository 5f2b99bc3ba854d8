"""The ``qhsm`` command's exit statuses beyond 0 (one place: the core and the service commands
share them)."""

#: An error was reported (a message on stderr, no traceback).
EXIT_FAILED = 1
#: Ctrl-C: as a shell reports a process ended by SIGINT (128 + 2).
EXIT_INTERRUPTED = 130
#: stdout's reader went away (``qhsm estimate ... | head``): as if killed by SIGPIPE (128 + 13).
EXIT_BROKEN_PIPE = 141
