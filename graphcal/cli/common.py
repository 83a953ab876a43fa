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
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

import typer
from rich.console import Console

from graphcal.core.atomic import protect, unprotect
from graphcal.core.errors import EstimationError, GraphcalInputError, os_error_message

#: Width used when the output is not a terminal (pipes, logs, ``make demo``) and the
#: environment variable ``COLUMNS`` does not give one.
PLAIN_WIDTH = 120


def plain_width() -> int:
    """Width of output that is not a terminal: ``COLUMNS`` when set, else :data:`PLAIN_WIDTH`."""
    try:
        width = int(os.environ.get("COLUMNS", ""))
    except ValueError:
        return PLAIN_WIDTH
    return width if width > 0 else PLAIN_WIDTH


#: Standard output: tables and summaries.
console = Console(width=None if sys.stdout.isatty() else plain_width())
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


#: Indent of the continuation lines of a wrapped message (:func:`print_wrapped`).
HANGING_INDENT = 2


def wrap_words(text: str, width: int, indent: int = HANGING_INDENT) -> list[str]:
    """``text`` as lines of at most ``width`` characters, broken at spaces only, the lines
    after the first indented by ``indent`` spaces (a hanging indent).

    A number, a name or a path is never cut: a word longer than a line stays whole on a
    line of its own.  Line breaks in ``text`` are kept.
    """
    import re
    import textwrap

    width = max(int(width), indent + 20)
    # "1.2 ± 0.3" and "12.5 s" stay on one line: their spaces become a character that
    # textwrap does not break at, put back afterwards.
    glue = "\ue000"
    text = re.sub(r"(?<=\d) (?=± )|(?<=±) (?=[-+]?\d)", glue, text)
    text = re.sub(r"(?<=\d) (?=(?:s|ms|m|km|mrad|deg|°|%|m²/s³)(?![\w/]))", glue, text)
    lines: list[str] = []
    for k, paragraph in enumerate(text.split("\n")):
        wrapped = textwrap.wrap(
            paragraph, width=width, initial_indent=" " * indent if k else "",
            subsequent_indent=" " * indent, break_long_words=False, break_on_hyphens=False)
        lines.extend(line.replace(glue, " ") for line in wrapped or [""])
    return lines


def print_wrapped(text: str, out: Console | None = None, *, label: str = "",
                  style: str | None = None, indent: int = HANGING_INDENT) -> None:
    """Print ``label text`` (e.g. ``warning: ...``, ``wrote PATH``) wrapped at the width
    of ``out`` (default :data:`console`; piped: ``COLUMNS`` or :data:`PLAIN_WIDTH`) with a
    hanging indent, at spaces only (:func:`wrap_words`).

    ``text`` is plain text, never rich markup (square brackets print as they are); only
    ``label`` takes ``style`` (e.g. ``"yellow"``).
    """
    from rich.text import Text

    out = console if out is None else out
    head = f"{label} " if label else ""
    for k, line in enumerate(wrap_words(head + text, out.width, indent)):
        shown = Text(line)
        if k == 0 and label and style:
            shown.stylize(style, 0, len(label))
        out.print(shown, highlight=False, soft_wrap=True)


def check_positive(value: float | None, option: str, what: str = "a positive number") -> None:
    """Refuse (exit 2) a number that is not finite and above zero (``None`` passes):
    ``--grid-s must be a positive number of seconds, not -1.0``."""
    import math

    if value is None:
        return
    if not (isinstance(value, int | float) and not isinstance(value, bool)
            and math.isfinite(value) and value > 0):
        fail(f"{option} must be {what}, not {value}", EXIT_BAD_INPUT)


def check_count(value: int | None, option: str, what: str = "a positive integer") -> None:
    """Refuse (exit 2) an integer below 1 (``None`` passes): ``--runs must be a positive
    integer, not 0``."""
    if value is not None and value < 1:
        fail(f"{option} must be {what}, not {value}", EXIT_BAD_INPUT)


def check_choice(value: str | None, option: str, choices: Sequence[str],
                 what: str = "value") -> None:
    """Refuse (exit 2) a ``value`` of ``option`` that is not one of ``choices``:
    ``--select: unknown selection method 'best'; use one of: greedy, ...`` (``what``:
    ``"selection method"``)."""
    if value is not None and value not in choices:
        fail(f"{option}: unknown {what} '{value}'; use one of: {', '.join(choices)}",
             EXIT_BAD_INPUT)


def check_seed(seed: int | None, option: str = "--seed") -> None:
    """Refuse (exit 2) a random seed that numpy cannot take: ``--seed -1: the seed must
    be a non-negative integer``."""
    if seed is not None and seed < 0:
        fail(f"{option} {seed}: the seed must be a non-negative integer (0, 1, 2, ...)",
             EXIT_BAD_INPUT)


def check_input_path(path: Path | None, option: str, *, folder: bool = False) -> None:
    """Refuse (exit 2) an input that is missing, or a file where a folder is wanted (and
    the reverse): ``"OPTION PATH: no such file"``."""
    if path is None:
        return
    label = f"{option} {path}" if option else str(path)
    if not path.exists():
        fail(f"{label}: no such {'folder' if folder else 'file'}", EXIT_BAD_INPUT)
    if folder and not path.is_dir():
        fail(f"{label}: not a folder", EXIT_BAD_INPUT)
    if not folder and path.is_dir():
        fail(f"{label}: is a folder; give a file", EXIT_BAD_INPUT)


def _resolved(path: Path) -> Path:
    return Path(os.path.abspath(path)).resolve()


def _inside(path: Path, folder: Path) -> bool:
    """``path`` is ``folder`` or lies below it (both resolved)."""
    return path == folder or folder in path.parents


def _writable_folder(folder: Path, label: str, *, create: bool) -> None:
    """The folder an output goes into: it must exist (or, with ``create``, its nearest
    existing ancestor must) and be a writable folder."""
    probe = folder
    if create:
        while not probe.exists() and probe != probe.parent:
            if probe.is_symlink():  # a dangling link
                break
            probe = probe.parent
    if not probe.exists():
        fail(f"{label}: folder {folder} does not exist", EXIT_BAD_INPUT)
    if not probe.is_dir():
        fail(f"{label}: {probe} is not a folder", EXIT_BAD_INPUT)
    if not os.access(probe, os.W_OK | os.X_OK):
        fail(f"{label}: cannot write in folder {probe} (permission denied)", EXIT_BAD_INPUT)


def _check_against_inputs(path: Path, label: str, inputs: Iterable[Path | None],
                          *, folder: bool) -> None:
    """Refuse an output that is an input, lies inside an input folder, or (a folder
    output) holds an input."""
    target = _resolved(path)
    for source in inputs:
        if source is None or not source.exists():
            continue
        given = _resolved(source)
        if target == given:
            fail(f"{label}: is the input {source}; write elsewhere", EXIT_BAD_INPUT)
        if source.is_dir() and _inside(target, given):
            fail(f"{label}: is inside the input folder {source}; write elsewhere",
                 EXIT_BAD_INPUT)
        if folder and _inside(given, target):
            fail(f"{label}: holds the input {source}; write elsewhere", EXIT_BAD_INPUT)


def check_output_file(path: Path | None, option: str, *, overwrite: bool | None = None,
                      inputs: Iterable[Path | None] = (),
                      suffixes: Sequence[str] | None = None) -> None:
    """Refuse (exit 2), before any work, an output file that cannot or must not be written.

    Checked: the suffix (when ``suffixes`` are given, case-insensitive), that ``path`` is
    not a folder, that its folder exists and is writable, that it is not an input and
    does not lie inside an input folder (``inputs``: dataset folders and input files),
    and, when ``overwrite`` is false, that it does not exist yet (``None``: replacing
    is allowed without asking).

    Parameters
    ----------
    path : Path or None
        The output (``None``: not asked for, nothing to check).
    option : str
        The option naming it in messages, e.g. ``"--out"``.
    overwrite : bool or None, optional
        ``False``: an existing file is refused (``pass --overwrite``).
    inputs : iterable of Path
        What the command reads.
    suffixes : sequence of str, optional
        Accepted suffixes, e.g. ``(".csv", ".parquet")``.
    """
    if path is None:
        return
    label = f"{option} {path}"
    if suffixes is not None and path.suffix.lower() not in suffixes:
        fail(f"{label}: the file must end in {' or '.join(suffixes)}", EXIT_BAD_INPUT)
    if path.is_dir():
        fail(f"{label}: is a folder; give a file name", EXIT_BAD_INPUT)
    _writable_folder(path.parent, label, create=False)
    _check_against_inputs(path, label, inputs, folder=False)
    if overwrite is False and (path.exists() or path.is_symlink()):
        fail(f"{label}: exists; pass --overwrite to replace it", EXIT_BAD_INPUT)
    # Published without replacing a file that another process writes meanwhile.
    if overwrite is False:
        protect(path)
    else:
        unprotect(path)


def check_output_folder(path: Path | None, option: str, *, overwrite: bool,
                        inputs: Iterable[Path | None] = ()) -> None:
    """Refuse (exit 2), before any work, a dataset folder that cannot or must not be written.

    ``path`` may be missing (it is created, with its missing parents, when the nearest
    existing one is a writable folder) or an empty folder; an existing file is refused,
    a non-empty folder without ``overwrite``, and a folder that is, lies inside or holds
    one of the ``inputs``.  ``None`` (not asked for): nothing to check.
    """
    if path is None:
        return
    label = f"{option} {path}"
    if path.name in ("", ".", "..") or _inside(Path.cwd().resolve(), _resolved(path)):
        fail(f"{label}: names the current folder or one that holds it; give the name of "
             "a new folder", EXIT_BAD_INPUT)
    if path.exists() and not path.is_dir():
        fail(f"{label}: exists and is not a folder", EXIT_BAD_INPUT)
    _check_against_inputs(path, label, inputs, folder=True)
    try:
        entries = sorted(p.name for p in path.iterdir()) if path.is_dir() else []
    except OSError as exc:
        fail(f"{label}: {os_error_message(exc)}", EXIT_BAD_INPUT)
    if entries and not overwrite:
        fail(f"{label}: folder exists and is not empty; pass --overwrite to replace it",
             EXIT_BAD_INPUT)
    if entries:
        foreign = foreign_entries(entries)
        if foreign:
            fail(f"{label}: folder is not a graphcal dataset (it holds "
                 f"{', '.join(repr(n) for n in foreign[:3])}"
                 f"{', ...' if len(foreign) > 3 else ''}); --overwrite only replaces a "
                 "dataset folder: remove it yourself or write elsewhere", EXIT_BAD_INPUT)
    _writable_folder(path.parent, label, create=True)


#: What a dataset folder written by graphcal holds (``--overwrite`` replaces only such
#: a folder).
DATASET_ENTRIES = frozenset({"sites.toml", "plots.csv", "plots.parquet", "adsb.csv",
                             "adsb.parquet", "plots", "adsb", "truth.json"})


def foreign_entries(names: Iterable[str]) -> list[str]:
    """The entries of a folder that make it something other than a graphcal dataset: every
    name that is not a dataset file (:data:`DATASET_ENTRIES`), or ``sites.toml`` itself
    when it is missing."""
    names = list(names)
    foreign = [n for n in names if n not in DATASET_ENTRIES]
    if "sites.toml" not in names and not foreign:
        foreign = ["no sites.toml"]
    return foreign


def check_distinct_outputs(*paths: tuple[str, Path | None]) -> None:
    """Refuse two outputs of one command that name the same file: ``(option, path)``."""
    seen: dict[Path, str] = {}
    for option, path in paths:
        if path is None:
            continue
        key = _resolved(path)
        if key in seen:
            fail(f"{option} {path}: {seen[key]} writes the same file", EXIT_BAD_INPUT)
        seen[key] = option


@contextmanager
def errors_to_exit() -> Iterator[None]:
    """Turn input and estimation errors into one-line messages and exit codes.

    An operating-system error (a full disk, a file-size limit, a read-only file system,
    a missing permission, a folder where a file is wanted, ...) is input or environment
    trouble too: ``error: <path>: disk full``, status 2.
    """
    try:
        yield
    except GraphcalInputError as exc:
        fail(str(exc), EXIT_BAD_INPUT)
    except EstimationError as exc:
        fail(str(exc), EXIT_ESTIMATION_FAILED)
    except OSError as exc:
        fail(os_error_message(exc), EXIT_BAD_INPUT)


#: Starts of numpy's floating-point warnings (and of its statistics on empty input):
#: graphcal checks its results for finite values itself (the fit verdict, the
#: observability warnings), so these say nothing more to the user.
QUIET_WARNINGS = ("invalid value encountered", "divide by zero encountered",
                  "overflow encountered", "underflow encountered", "Mean of empty slice",
                  "Degrees of freedom <= 0", "All-NaN slice", "All-NaN axis",
                  "invalid value in", "Sending large graph")


def route_warnings() -> None:
    """Python warnings as graphcal's own one-line ``warning: ...`` messages.

    numpy's floating-point warnings (:data:`QUIET_WARNINGS`) are dropped; any other
    warning prints one line on standard error, without the file and source line of a
    raw Python warning.  Warning options given to Python (``-W``, ``PYTHONWARNINGS``)
    keep Python's own handling, for developers.
    """
    import warnings

    if sys.warnoptions:
        return

    def show(message: Warning | str, category: type[Warning], filename: str, lineno: int,
             file: object = None, line: str | None = None) -> None:
        text = " ".join(str(message).split())
        if any(start in text for start in QUIET_WARNINGS):
            return
        try:
            err_console.print(f"warning: {text}", highlight=False, soft_wrap=True,
                              markup=False)
        except (OSError, ValueError):
            pass

    warnings.showwarning = show


#: The signal that ended the command, once :func:`install_signal_handlers`' handler ran
#: (the exit it raises can surface as another exception, e.g. inside an extension's import).
TERMINATED_BY: list[int] = []


def install_signal_handlers() -> None:
    """SIGTERM ends the command as an interruption (``SystemExit(143)`` in the main
    thread), so every ``finally`` and ``with`` block runs and temporary files and
    folders are removed; SIGXFSZ (a file-size limit) is ignored, so that the write
    fails with "file too large" instead of killing the process."""
    import signal

    if threading.current_thread() is not threading.main_thread():
        return
    owner = os.getpid()

    def terminate(signum: int, frame: object) -> None:
        if os.getpid() != owner:  # a forked worker: die as by default
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        signal.signal(signum, signal.SIG_DFL)  # a second SIGTERM ends at once
        TERMINATED_BY.append(signum)
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, terminate)
    if hasattr(signal, "SIGXFSZ"):
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)


@contextmanager
def outputs_published_together() -> Iterator[None]:
    """Hold back SIGTERM and SIGINT while a command publishes its outputs.

    A command that writes several files (``calibrate --out --report --cat063
    --history``) builds them first and publishes them in this block; a termination
    asked for meanwhile takes effect when the block ends, so an interruption never
    leaves some of the outputs without the others.  Outside the main thread (or
    where signals cannot be masked) it does nothing.
    """
    import signal

    held = {signal.SIGTERM, signal.SIGINT}
    if (threading.current_thread() is not threading.main_thread()
            or not hasattr(signal, "pthread_sigmask")):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


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
    "HANGING_INDENT",
    "PLAIN_PROGRESS_INTERVAL_S",
    "PLAIN_WIDTH",
    "TERMINATED_BY",
    "command_line",
    "check_choice",
    "check_count",
    "check_distinct_outputs",
    "check_input_path",
    "check_positive",
    "check_seed",
    "foreign_entries",
    "install_signal_handlers",
    "outputs_published_together",
    "check_output_file",
    "check_output_folder",
    "console",
    "cat063_codes",
    "err_console",
    "errors_to_exit",
    "fail",
    "parse_sac_sic",
    "route_warnings",
    "plain_width",
    "print_wrapped",
    "progress_bar",
    "wrap_words",
]
