"""What every command shares: the consoles, the exit codes, errors as one-line messages, the
progress bar (plain progress lines when standard error is not a terminal).

A leaf of :mod:`graphcal.cli`: it imports no other command-line module, so every command
module can import it and :mod:`graphcal.cli.app` can import every command module.  It
stays light (no numpy), because ``graphcal --help`` imports it.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

import typer
from rich.console import Console

from graphcal.core.errors import EstimationError, GraphcalInputError

#: Width used when the output is not a terminal (pipes, logs, ``make demo``).
PLAIN_WIDTH = 120
#: Standard output: tables and summaries.
console = Console(width=None if sys.stdout.isatty() else PLAIN_WIDTH)
#: Standard error: errors, warnings about files, ``wrote FILE`` lines, progress bars.
err_console = Console(stderr=True)

#: Seconds between plain progress lines (standard error not a terminal); the environment
#: variable ``GRAPHCAL_PROGRESS_S`` overrides it.
PLAIN_PROGRESS_INTERVAL_S = 5.0

#: Exit status for bad input.
EXIT_BAD_INPUT = 2
#: Exit status when the data do not allow an estimate.
EXIT_ESTIMATION_FAILED = 3

#: Help of ``--force`` (every command that reads a dataset folder).
FORCE_HELP = ("Proceed even when the data look like a unit or frame mistake (azimuth in "
              "radians, range in km, heights in feet, ADS-B latitude and longitude swapped, "
              "an implausible antenna height, ADS-B on another time base); see "
              "docs/data-formats.md.")


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
    """A progress display yielding ``callback([stage,] done, total)``.

    On a terminal a rich progress bar on standard error.  Otherwise (a pipe, a log
    file) plain lines on standard error, at most one every
    :data:`PLAIN_PROGRESS_INTERVAL_S` seconds and only while the work lasts that long,
    e.g. ``graphcal: graph: optimising, 15 s`` or ``graphcal: graph: ADS-B association
    50% (2/4), 10 s``: a short run prints nothing.
    """
    if not err_console.is_terminal:
        with _plain_progress(description) as callback:
            yield callback
        return
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


def parse_sac_sic(items: Iterable[str]) -> dict[str, tuple[int, int]]:
    """``--sac-sic RADAR=SAC/SIC`` options -> ``{radar: (SAC, SIC)}``; exit 2 on a bad one."""
    codes: dict[str, tuple[int, int]] = {}
    for item in items:
        rid, sep, text = item.rpartition("=")
        sac, slash, sic = text.partition("/")
        try:
            if not sep or not rid.strip() or not slash:
                raise ValueError
            code = (int(sac), int(sic))
        except ValueError:
            fail(f"--sac-sic {item!r}: expected RADAR=SAC/SIC, e.g. NORD=25/201", EXIT_BAD_INPUT)
        if not all(0 <= v <= 255 for v in code):
            fail(f"--sac-sic {item!r}: SAC and SIC must be within 0..255", EXIT_BAD_INPUT)
        if rid.strip() in codes:
            fail(f"--sac-sic {item!r}: radar {rid.strip()} given twice", EXIT_BAD_INPUT)
        codes[rid.strip()] = code
    return codes


def cat063_codes(cat063: Path | None, sac_sic: Iterable[str] | None,
                 sites: Mapping[str, Any], radar_ids: Iterable[str]
                 ) -> dict[str, tuple[int, int]]:
    """``--cat063 FILE`` and ``--sac-sic``: the SAC/SIC of every radar, checked before any
    estimation.

    Codes come from ``--sac-sic RADAR=SAC/SIC`` (repeatable), else from the ``sac``/``sic``
    keys of the radar's ``sites.toml`` table, else from an id like ``SAC025_SIC201``.  Exits
    with status 2 naming every radar without a code, a bad option or a file name whose
    suffix is not a CAT063 format.  Returns ``{}`` without ``--cat063``.
    """
    given = parse_sac_sic(sac_sic or [])
    if cat063 is None:
        if given:
            fail("--sac-sic applies to --cat063 FILE", EXIT_BAD_INPUT)
        return {}
    from graphcal.io.asterix.cat063 import CAT063_SUFFIXES, radar_codes_for
    from graphcal.io.asterix.encode import AsterixEncodeError

    if cat063.suffix.lower() not in CAT063_SUFFIXES:
        fail(f"--cat063 {cat063}: the file must end in {', '.join(CAT063_SUFFIXES)}",
             EXIT_BAD_INPUT)
    site_codes = {rid: (int(site.sac), int(site.sic)) for rid, site in sites.items()
                  if getattr(site, "sac", None) is not None
                  and getattr(site, "sic", None) is not None}
    try:
        codes = radar_codes_for(radar_ids, site_codes, given)
    except AsterixEncodeError as exc:
        fail(f"--cat063 {cat063}: {exc}", EXIT_BAD_INPUT)
    # Radars without plots keep the codes their tables give (not required).
    return {**{rid: code for rid, code in site_codes.items() if rid not in codes}, **codes}


def _progress_interval() -> float:
    """:data:`PLAIN_PROGRESS_INTERVAL_S`, or ``GRAPHCAL_PROGRESS_S`` when set to a number."""
    try:
        value = float(os.environ.get("GRAPHCAL_PROGRESS_S", PLAIN_PROGRESS_INTERVAL_S))
    except ValueError:
        return PLAIN_PROGRESS_INTERVAL_S
    return value if value > 0 else PLAIN_PROGRESS_INTERVAL_S


@contextmanager
def _plain_progress(description: str) -> Iterator[Callable[..., None]]:
    """Plain progress lines from a timer thread; the callback only records the state."""
    interval = _progress_interval()
    start = time.monotonic()
    state: list[object] = ["", 0, None]  # stage, done, total
    lock = threading.Lock()
    stop = threading.Event()

    def callback(*args: object) -> None:
        with lock:
            state[3 - len(args):] = args

    def report() -> None:
        while not stop.wait(interval):
            with lock:
                stage, done, total = state
            line = f"graphcal: {description}"
            if stage:
                line += f": {stage}"
            if isinstance(done, int | float) and isinstance(total, int | float) and total > 1:
                line += f" {100.0 * done / total:.0f}% ({done}/{total})"
            line += f", {time.monotonic() - start:.0f} s"
            try:
                print(line, file=sys.stderr, flush=True)
            except (OSError, ValueError):  # the stream went away
                return

    thread = threading.Thread(target=report, name="graphcal-progress", daemon=True)
    thread.start()
    try:
        yield callback
    finally:
        stop.set()
        thread.join()


def command_line() -> str:
    """This process's command line as ``graphcal ARGS`` (quoted for a shell), e.g. for the
    header of a report."""
    import shlex

    return shlex.join(["graphcal", *sys.argv[1:]])


__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_ESTIMATION_FAILED",
    "FORCE_HELP",
    "PLAIN_PROGRESS_INTERVAL_S",
    "PLAIN_WIDTH",
    "command_line",
    "console",
    "cat063_codes",
    "err_console",
    "errors_to_exit",
    "fail",
    "parse_sac_sic",
    "progress_bar",
]
