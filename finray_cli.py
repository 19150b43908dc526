"""The `finray` console script's entry point: Ctrl-C ends any command, at any moment,
with exit status 130 and one line.

This module imports nothing heavy before it takes charge of SIGINT, so an interrupt
during the (seconds long) import of jax is handled too: it ends the process at once
(nothing has been done yet, and an import interrupted halfway may print its own
traceback). SIGINT is blocked in every
thread (the mask is inherited by the threads jax and XLA start later) and waited for by
one thread of its own, which sees it at once even while the main thread sits in a long
XLA compilation. On the first Ctrl-C that thread raises KeyboardInterrupt in the main
thread, where the command stops, says what it kept (a sweep's finished rows, an
optimisation's record) and returns 130. Where the interrupt lands in code that cannot
raise it (a garbage-collection callback: Python would print "Exception ignored" and run
on), the process ends at once; where the main thread does not stop within GRACE seconds
(native code that runs on), or on a second Ctrl-C, likewise. Everything a command keeps
on disk is written atomically, so it loses only unfinished work.

The process always leaves through `os._exit` after an interrupt: a normal interpreter
shutdown with XLA's threads mid-flight can crash in their destructors.
"""

import _thread
import os
import signal
import sys
import threading

EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports it
GRACE = 5.0  # seconds the command has to stop cleanly after the first Ctrl-C
LINE = "\nfinray: interrupted"  # (a progress bar may hold the line: start a new one)

_interrupted = threading.Event()
_finished = threading.Event()
_importing = threading.Event()


def _leave(code: int) -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def _end_interrupted() -> None:
    """Say the one line and end the process with 130, at once."""
    _finished.set()
    print(LINE, file=sys.stderr)
    _leave(EXIT_INTERRUPTED)


def _watch() -> None:
    """Wait for SIGINT; interrupt the main thread, then make sure the process ends."""
    signal.sigwait({signal.SIGINT})
    _interrupted.set()
    if _importing.is_set():  # nothing done yet: no need to stop cleanly
        _end_interrupted()
    _thread.interrupt_main()
    signal.sigtimedwait({signal.SIGINT}, GRACE)  # (a second Ctrl-C ends the wait early)
    if not _finished.is_set():
        _end_interrupted()


def _unraisable(hook_args) -> None:
    """An interrupt that landed where Python cannot raise it (a garbage-collection
    callback, a destructor) ends the process at once, with the one line; any other
    unraisable exception is shown as Python shows it."""
    if issubclass(hook_args.exc_type, KeyboardInterrupt):
        _end_interrupted()
    sys.__unraisablehook__(hook_args)


def main() -> None:
    """Run `finray_jax.cli.main` with SIGINT handled as the module docstring says."""
    if threading.current_thread() is threading.main_thread() and hasattr(signal, "sigwait"):
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        threading.Thread(target=_watch, name="finray-sigint", daemon=True).start()
        sys.unraisablehook = _unraisable
    try:
        _importing.set()
        from finray_jax.cli import main as cli_main

        _importing.clear()
        code = cli_main()
    except BaseException:
        # An interrupt during the imports, or let through by a command; native modules
        # may turn it into another exception (jaxlib's extension reports an ImportError).
        if not _interrupted.is_set():
            raise
        _end_interrupted()
    if _interrupted.is_set():  # the command stopped cleanly and said so
        _finished.set()
        _leave(EXIT_INTERRUPTED)
    sys.exit(code)


if __name__ == "__main__":
    main()
