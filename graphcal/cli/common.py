"""What every command shares: the consoles, the exit codes, errors as one-line messages, the
progress bar.

A leaf of :mod:`graphcal.cli`: it imports no other command-line module, so every command
module can import it and :mod:`graphcal.cli.app` can import every command module.  It
stays light (no numpy), because ``graphcal --help`` imports it.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import NoReturn

import typer
from rich.console import Console

from graphcal.core.errors import EstimationError, GraphcalInputError

#: Width used when the output is not a terminal (pipes, logs, ``make demo``).
PLAIN_WIDTH = 120
#: Standard output: tables and summaries.
console = Console(width=None if sys.stdout.isatty() else PLAIN_WIDTH)
#: Standard error: errors, warnings about files, ``wrote FILE`` lines, progress bars.
err_console = Console(stderr=True)

#: Exit status for bad input.
EXIT_BAD_INPUT = 2
#: Exit status when the data do not allow an estimate.
EXIT_ESTIMATION_FAILED = 3


def fail(message: str, status: int) -> NoReturn:
    """Print ``error: message`` on one line of standard error and exit with ``status``."""
    err_console.print(f"error: {message}", highlight=False, soft_wrap=True, markup=False)
    raise typer.Exit(status)


@contextmanager
def errors_to_exit() -> Iterator[None]:
    """Turn input and estimation errors into one-line messages and exit codes."""
    try:
        yield
    except GraphcalInputError as exc:
        fail(str(exc), EXIT_BAD_INPUT)
    except EstimationError as exc:
        fail(str(exc), EXIT_ESTIMATION_FAILED)


@contextmanager
def progress_bar(description: str) -> Iterator[Callable[..., None]]:
    """A rich progress bar yielding ``callback([stage,] done, total)``; silent off a terminal."""
    from rich.progress import (
        BarColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console,
        transient=True,
        disable=not err_console.is_terminal,
    )
    with progress:
        task = progress.add_task(description, total=None)

        def callback(*args: object) -> None:
            if len(args) == 3:
                stage, done, total = args
                progress.update(task, description=f"{description}: {stage}")
            else:
                done, total = args
            progress.update(task, completed=done, total=total)

        yield callback


__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_ESTIMATION_FAILED",
    "PLAIN_WIDTH",
    "console",
    "err_console",
    "errors_to_exit",
    "fail",
    "progress_bar",
]
