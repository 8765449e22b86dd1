"""Exit codes of the ``rig`` command (documented in docs/reference/exit_codes.md and the README)."""

SUCCESS = 0
UNEXPECTED_ERROR = 1
BAD_INPUT = 2  # also argparse's own code for a usage error
DEVICE_FAULT = 3  # a device reported a fault or the link to it failed
EMPTY_FEASIBLE_SET = 4  # the data contradict the model structure and the noise bound
WRITE_FAILED = 5  # the output could not be written (path not writable, disk full); what was flushed is kept
INTERRUPTED = 130  # Ctrl-C (SIGINT), after a controlled stop: 128 + 2
TERMINATED = 143  # SIGTERM, after a controlled stop: 128 + 15
