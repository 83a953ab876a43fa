"""The ``graphcal`` command line: the typer app, one command per module of :mod:`graphcal.cli`.

Bad input prints one line ``error: <file>, row N, field 'x': what is wrong``
and exits with status 2 (:mod:`graphcal.cli.common`); so does trouble with the
environment (``error: out.json: disk full``), never a traceback.
"""

from __future__ import annotations

import inspect
import os
import sys
from collections.abc import Callable
from typing import Annotated

import typer

from graphcal.cli.calibrate import calibrate_command
from graphcal.cli.common import (
    EXIT_BAD_INPUT,
    TERMINATED_BY,
    console,
    install_signal_handlers,
    route_warnings,
)
from graphcal.cli.compare import compare_command
from graphcal.cli.correct import correct_command
from graphcal.cli.fuse import fuse_command
from graphcal.cli.history import history_command
from graphcal.cli.import_asterix import import_asterix_command
from graphcal.cli.marginals import marginals_command
from graphcal.cli.methods import methods_command
from graphcal.cli.noise import noise_command
from graphcal.cli.observability import observability_command
from graphcal.cli.report import report_command
from graphcal.cli.simulate import simulate_command
from graphcal.core.allocator import keep_freed_memory

app = typer.Typer(
    help="Joint bias calibration of air-surveillance radar networks.",
    no_args_is_help=True,
    add_completion=False,
    # Plain help: an option per line and its text wrapped beside it, readable at 80
    # columns and when piped (rich's panels leave calibrate's texts a column of 20).
    rich_markup_mode=None,
    # A defect prints one line (main); GRAPHCAL_DEBUG=1 gives Python's plain traceback.
    pretty_exceptions_enable=False,
)



def _print_version(value: bool) -> None:
    """``--version``: print ``graphcal VERSION`` and stop."""
    if value:
        from graphcal import __version__

        console.print(f"graphcal {__version__}", highlight=False)
        raise typer.Exit()


@app.callback()
def _options(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_print_version, is_eager=True,
                     help="Print graphcal's version and exit."),
    ] = False,
) -> None:
    """Joint bias calibration of air-surveillance radar networks."""
    from graphcal.core.atomic import clear_protected

    clear_protected()  # what an earlier command (in this process) protected


def _summary(command: Callable[..., object]) -> str:
    """The first paragraph of a command's docstring, on one line: its line in ``--help``
    (given whole, so that the list is wrapped at the terminal's width, not cut)."""
    return " ".join((inspect.getdoc(command) or "").split("\n\n")[0].split())


for _name, _command in [
    ("simulate", simulate_command), ("calibrate", calibrate_command),
    ("noise", noise_command), ("fuse", fuse_command), ("methods", methods_command),
    ("marginals", marginals_command), ("compare", compare_command),
    ("import-asterix", import_asterix_command), ("observability", observability_command),
    ("report", report_command), ("correct", correct_command), ("history", history_command),
]:
    app.command(name=_name, short_help=_summary(_command))(_command)


#: Environment variable that lets a defect's traceback through (``GRAPHCAL_DEBUG=1``).
DEBUG_ENV = "GRAPHCAL_DEBUG"
#: Exit status of a defect of graphcal itself (an unexpected exception).
EXIT_INTERNAL_ERROR = 1
#: Exit status after Ctrl-C (128 + SIGINT), as shells report it.
EXIT_INTERRUPTED = 130


def main() -> None:  # pragma: no cover - console entry point
    """Run the command line (what ``python -m graphcal`` and the ``graphcal`` script do),
    then end the process at once (:func:`exit_at_once`)."""
    install_signal_handlers()
    route_warnings()
    keep_freed_memory()
    try:
        app()
        status: object = 0
    except SystemExit as exc:
        status = exc.code
    except OSError as exc:  # an environment error no command turned into a message
        from graphcal.core.errors import os_error_message

        _say(f"error: {os_error_message(exc)}")
        status = EXIT_BAD_INPUT
    except KeyboardInterrupt:
        _say("error: interrupted")
        status = EXIT_INTERRUPTED
    except MemoryError:
        _say("error: out of memory; calibrate a long recording in windows (--window 1h)")
        status = EXIT_BAD_INPUT
    except Exception as exc:  # a defect of graphcal: one line, the traceback on request
        if TERMINATED_BY:  # SIGTERM's exit, wrapped by the code it interrupted (an import)
            _say("error: terminated")
            exit_at_once(128 + TERMINATED_BY[0])
            return
        if os.environ.get(DEBUG_ENV):
            raise
        _say(f"error: internal error ({type(exc).__name__}: {exc}); please report it with "
             f"the command line; {DEBUG_ENV}=1 shows the traceback")
        status = EXIT_INTERNAL_ERROR
    exit_at_once(status)


def _say(line: str) -> None:
    """One line on standard error, whatever state the stream is in."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def exit_at_once(status: object) -> None:
    """End the process with ``status`` (as :class:`SystemExit` reads it), skipping the
    interpreter's teardown.

    Python's own shutdown frees every loaded module one object at a time; with pandas,
    SciPy and GTSAM loaded that is a quarter of a second after the command's work is
    done.  Everything else a normal exit does still happens: the exit handlers run
    (``atexit``: temporary files, child processes) and the standard streams are
    flushed.  Only the freeing of memory, which the operating system does at once, is
    skipped.  While a thread that is not a daemon is alive (a worker pool left open,
    say), the exit is the normal one, which knows how to end such threads.
    """
    import atexit
    import os
    import threading

    main_thread = threading.main_thread()
    if any(t is not main_thread and not t.daemon and t.is_alive()
           for t in threading.enumerate()):
        sys.exit(status)
    if status is None:
        code = 0
    elif isinstance(status, int):
        code = status
    else:  # SystemExit("message"): the message on stderr, status 1
        print(status, file=sys.stderr)
        code = 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe or stream: nothing more to say
            pass
    os._exit(code & 0xFF)  # as the operating system reads a larger status


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
