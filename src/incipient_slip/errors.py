"""The usage error every command raises and the exit codes every process returns.

One place for both, below every package, so that the `slip` command, the launcher, the nodes
and the experiments agree on what an exit code means.
"""
from __future__ import annotations

EXIT_SUCCESS = 0        # the run did what was asked (supervisor: the object was held)
EXIT_FAILURE = 1        # the run ended on the paper's failure condition, or a process crashed
EXIT_USAGE = 2          # bad input on the command line, in a parameter or a file it names
EXIT_FAULT = 3          # the supervisor ended the run because the graph misbehaved
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT), as a shell reports it
EXIT_SIGNAL_BASE = 128  # a node stopped by signal N, after its clean stop: 128 + N (130 SIGINT,
                        # 143 SIGTERM), as a shell reports it; a launch ended by one exits with it


class UsageError(Exception):
    """Bad input from the user; `slip` prints it as one line on stderr and exits EXIT_USAGE."""
