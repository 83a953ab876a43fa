"""Where the window map runs: in this process, or on Dask (``calibrate --scheduler``).

Each window's summary (:func:`graphcal.solvers.windows.summarise_window`) is
independent work.  :func:`map_windows` runs it over the windows as they are read:

* ``synchronous``: one after the other, in this process (no Dask).
* ``forked``: this process and a copy of it forked at the start (Linux), each taking
  the next window when it is free (:func:`map_forked`): two cores calibrate while a
  forked reader reads ahead.
* ``auto`` (the default, ``None``): ``forked`` where the windows come from a forked
  reader (a large folder, :mod:`graphcal.pipeline.window_feed`) on two or more
  cores, else ``synchronous``.
* ``threads``: a Dask ``distributed`` cluster of threads in this process.
* ``processes``: a ``distributed`` ``LocalCluster`` of one single-threaded worker
  process per core.
* an address (``tcp://host:8786``, ``tls://...``, ``host:port``): the workers of an
  existing cluster, so a site with many machines runs the same command (start
  ``dask scheduler`` on one machine and ``dask worker tcp://host:8786`` on each of
  the others, with graphcal installed on all).

At most two windows per worker thread are in flight, so memory stays bounded by a
few windows however long the recording.  The results come back in window order and
do not depend on the scheduler.
"""

from __future__ import annotations

import os
import queue
import signal
import threading
import warnings
import weakref
from collections.abc import Callable, Iterable, Iterator
from typing import Any

#: The scheduler names; anything else is taken as a cluster address.
SCHEDULERS = ("auto", "synchronous", "forked", "threads", "processes")

Progress = Callable[..., None]


def check_scheduler(scheduler: str | None) -> str:
    """The scheduler's name (``synchronous`` for ``None``) or a plausible address.

    Raises
    ------
    ValueError
        For a name that is neither a scheduler nor an address, naming the choices.
    """
    if scheduler is None or scheduler == "":
        return "auto"
    if scheduler in SCHEDULERS or "://" in scheduler or ":" in scheduler:
        return scheduler
    raise ValueError(
        f"unknown scheduler '{scheduler}': use auto, synchronous, forked, threads, "
        "processes, or the "
        "address of a Dask scheduler (e.g. tcp://10.0.0.5:8786)")


def quiet_large_graphs() -> None:
    """Silence Dask's "Sending large graph of size ..." warning: the windows travel as
    scattered data (:func:`_map_on_dask`), and the warning only says that a window is
    big, which is expected and nothing the user can act on."""
    warnings.filterwarnings("ignore", message=r"(?s).*Sending large graph", category=UserWarning)


def _client(scheduler: str) -> Any:
    quiet_large_graphs()
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover - distributed is a dependency
        raise ValueError(f"--scheduler {scheduler} needs Dask distributed: {exc}") from None
    cores = os.cpu_count() or 1
    if scheduler == "threads":
        cluster = LocalCluster(n_workers=1, threads_per_worker=cores, processes=False,
                               dashboard_address=None)
        return Client(cluster)
    if scheduler == "processes":
        cluster = LocalCluster(n_workers=cores, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        return Client(cluster)
    try:
        return Client(scheduler, timeout="10s")
    except OSError as exc:
        raise ValueError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None


def read_ahead(items: Iterable[Any], depth: int = 1) -> Iterator[Any]:
    """The items of ``items``, the next ``depth`` of them produced by a thread meanwhile.

    Reading a window (CSV parsing, validation, cleaning: much of it in pandas and
    numpy code that releases the GIL) then overlaps with calibrating the one before
    on a second core.  The order is kept; an exception of the producer is raised
    here, at the item it stopped at; at most ``depth + 1`` items are held.
    Abandoning the iterator stops the producer at its next item.
    """
    out: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    done = object()

    def produce() -> None:
        try:
            for item in items:
                while not stop.is_set():
                    try:
                        out.put((item, None), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            out.put((done, exc))
            return
        out.put((done, None))

    thread = threading.Thread(target=produce, name="graphcal-read-ahead", daemon=True)
    thread.start()
    try:
        while True:
            item, error = out.get()
            if item is done:
                if error is not None:
                    raise error
                return
            yield item
    finally:
        stop.set()
        while thread.is_alive():
            try:
                out.get_nowait()
            except queue.Empty:
                thread.join(timeout=0.1)


def child_reading_available() -> bool:
    """Whether :func:`read_in_child` can fork a reading process here (Linux)."""
    import multiprocessing
    import sys

    return sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods()


def read_in_child(function: Callable[..., Iterable[Any]], args: tuple[Any, ...] = ()
                  ) -> Iterator[Any]:
    """The items of ``function(*args)``, produced meanwhile in a forked child process.

    Like :func:`read_ahead`, but the reading (CSV parsing, validation, cleaning) runs
    in its own interpreter and so never waits for this one's GIL: on two cores
    reading a window and calibrating the one before truly overlap.  The child is
    forked at once, before the first item is asked for, with this process's modules
    and caches; it takes none of this process's locks: its standard streams are new
    objects, and the warnings it raises are sent here and raised again in order.
    Each item is pickled by the child's main thread and written to a pipe by a
    second thread, which spends its time in ``write`` calls that release the GIL (a
    queue's feeder thread, which also pickles, slowed the reading by a fifth).  The
    child so runs ahead of this process by up to :data:`CHILD_AHEAD_BYTES` of pickled
    items (a window that takes long to read is then absorbed by those read before
    it); this process reads an item when it asks for it.  ``args`` and the items must
    be picklable.  The order is kept; an exception of the producer is raised here at
    the item it stopped at.  Closing or abandoning the iterator stops the child.
    Where forking is not available (:func:`child_reading_available`), the items come from
    :func:`read_ahead` instead.

    Returns
    -------
    iterator
        With a ``close()`` method.

    Raises
    ------
    RuntimeError
        While iterating: if the child dies without a word (killed, out of memory).
    """
    if not child_reading_available():
        return read_ahead(function(*args))
    import multiprocessing

    context = multiprocessing.get_context("fork")
    reader, writer = context.Pipe(duplex=False)
    _widen_pipe(writer.fileno())
    child = context.Process(target=_produce_into, args=(function, args, reader, writer),
                            name="graphcal-reader", daemon=True)
    with warnings.catch_warnings():
        # Python 3.12+ warns that a child forked from a process with threads may wait
        # forever on a lock one of them held: this child takes none (see above).
        warnings.filterwarnings("ignore", message=r".*fork\(\) may lead to deadlocks",
                                category=DeprecationWarning)
        child.start()
    writer.close()  # the child's end: end of file here when the child is gone
    return ChildItems(child, reader)


class ChildItems(Iterator[Any]):
    """The items a forked child sends over a pipe (:func:`read_in_child`).

    Parameters
    ----------
    child : multiprocessing.Process
        The started child.
    reader : multiprocessing.connection.Connection
        This process's end of the pipe.
    """

    def __init__(self, child: Any, reader: Any) -> None:
        self._child = child
        self._reader = reader
        self._items = self._receive()
        # Stops the child when this object is closed, collected, or the process ends.
        self._stop = weakref.finalize(self, _stop_child, child, reader)

    def __iter__(self) -> ChildItems:
        return self

    def __next__(self) -> Any:
        return next(self._items)

    def close(self) -> None:
        """Stop the child (the items not yet read are lost)."""
        self._items.close()
        self._stop()

    def _receive(self) -> Iterator[Any]:
        import pickle

        try:
            while True:
                try:
                    kind, payload = pickle.loads(self._reader.recv_bytes())
                except EOFError:
                    self._child.join(timeout=5.0)
                    raise RuntimeError(
                        f"the reading process stopped (exit code {self._child.exitcode}) "
                        "before the end of the data; out of memory?") from None
                if kind == "item":
                    yield payload
                elif kind == "warning":
                    message, category, filename, lineno = payload
                    warnings.warn_explicit(message, category, filename, lineno)
                elif kind == "error":
                    raise payload
                else:
                    return
        finally:
            self._stop()


def _stop_child(child: Any, reader: Any) -> None:
    """Close this end of the pipe (a child still writing gets a broken pipe and stops),
    then wait for the child, terminating it if it does not stop."""
    reader.close()
    child.join(timeout=1.0)
    if child.is_alive():
        child.terminate()
        child.join()


#: How far (pickled bytes) the reading child may run ahead of this process, beyond
#: the item it is writing: the items wait in the child's memory until this process
#: asks for them.  At least one whole item is always held, however large.
CHILD_AHEAD_BYTES = 64 << 20


class _Outbox:
    """The child's pickled items, written to the pipe by a thread in their order.

    The producer goes on with the next item while this process is still busy with
    an earlier one, up to ``budget`` bytes held; the writing thread spends its time
    in ``write`` calls, which release the GIL, so it hardly slows the producer.

    Parameters
    ----------
    writer : multiprocessing.connection.Connection
        The child's end of the pipe.
    budget : int
        Bytes [B] held before :meth:`put` waits (one item is always accepted).
    """

    def __init__(self, writer: Any, budget: int) -> None:
        import collections

        self._writer = writer
        self._budget = budget
        self._items: collections.deque[bytes | None] = collections.deque()
        self._held = 0
        self._broken = False
        self._changed = threading.Condition()
        self._thread = threading.Thread(target=self._write_out, name="graphcal-outbox",
                                        daemon=True)
        self._thread.start()

    def put(self, data: bytes) -> None:
        """Queue ``data``; waits while the budget is used.

        Raises
        ------
        BrokenPipeError
            When the other end stopped reading.
        """
        with self._changed:
            while self._held and self._held + len(data) > self._budget and not self._broken:
                self._changed.wait()
            if self._broken:
                raise BrokenPipeError("the reading side closed the pipe")
            self._items.append(data)
            self._held += len(data)
            self._changed.notify_all()

    def finish(self) -> None:
        """Wait until every queued item is written.

        Raises
        ------
        BrokenPipeError
            When the other end stopped reading first.
        """
        with self._changed:
            self._items.append(None)
            self._changed.notify_all()
        self._thread.join()
        if self._broken:
            raise BrokenPipeError("the reading side closed the pipe")

    def abandon(self) -> None:
        """Drop what is not written yet and stop the writing thread (it is a daemon:
        one blocked on a full pipe ends with the process)."""
        with self._changed:
            self._items.clear()
            self._items.append(None)
            self._changed.notify_all()

    def _write_out(self) -> None:
        while True:
            with self._changed:
                while not self._items:
                    self._changed.wait()
                data = self._items[0]
            if data is None:
                return
            try:
                self._writer.send_bytes(data)
            except OSError:
                with self._changed:
                    self._broken = True
                    self._changed.notify_all()
                return
            with self._changed:
                if self._items and self._items[0] is data:
                    self._items.popleft()
                    self._held -= len(data)
                self._changed.notify_all()


def _widen_pipe(fd: int, size: int = 1 << 20) -> None:
    """Ask Linux for a pipe buffer of ``size`` bytes (fewer, larger writes); best effort."""
    import fcntl

    set_size = getattr(fcntl, "F_SETPIPE_SZ", 1031)
    try:
        fcntl.fcntl(fd, set_size, size)
    except OSError:
        pass


def _exit_on_signal(signum: int, frame: Any) -> None:
    raise SystemExit(128 + signum)


def _travelling(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling (to be raised in the parent), else a
    :class:`RuntimeError` with its type and message."""
    import pickle

    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:  # noqa: BLE001 - an exception that cannot travel as it is
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


def _produce_into(function: Callable[..., Iterable[Any]], args: tuple[Any, ...],
                  reader: Any, writer: Any) -> None:
    """:func:`read_in_child`'s child: every item and warning, then the end or the error."""
    import pickle
    import sys

    reader.close()
    # Stopped from the parent (terminate): unwind, so that the reader's temporary
    # files are removed.
    signal.signal(signal.SIGTERM, _exit_on_signal)
    # New stream objects: the inherited ones' locks may be held by a thread that was
    # not forked.
    sys.stdout = open(os.dup(1), "w", closefd=True)  # noqa: SIM115 - for the child's life
    sys.stderr = open(os.dup(2), "w", closefd=True)  # noqa: SIM115

    outbox = _Outbox(writer, CHILD_AHEAD_BYTES)

    def put(message: tuple[str, Any]) -> None:
        outbox.put(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))

    def send_warnings(caught: list[warnings.WarningMessage]) -> None:
        for w in caught:
            put(("warning", (str(w.message), w.category, w.filename, w.lineno)))
        caught.clear()

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            try:
                for item in function(*args):
                    send_warnings(caught)
                    put(("item", item))
                ending: tuple[str, Any] = ("end", None)
            except (KeyboardInterrupt, BrokenPipeError):
                raise
            except BaseException as exc:  # noqa: BLE001 - handed to the parent
                ending = ("error", _travelling(exc))
            send_warnings(caught)
            put(ending)
            outbox.finish()
        except (KeyboardInterrupt, BrokenPipeError):
            return  # interrupted, or the parent stopped reading
        finally:
            outbox.abandon()
            writer.close()


def map_windows(
    function: Callable[..., Any],
    items: Iterable[Any],
    *,
    scheduler: str | None = None,
    args: tuple[Any, ...] = (),
    progress: Progress | None = None,
    total: int | None = None,
    stage: str = "windows",
    prefetch: bool = True,
    prepare: Callable[[int], None] | None = None,
    helper: ForkedHelper | None = None,
) -> Iterator[Any]:
    """``function(item, *args)`` for every item, in item order.

    Parameters
    ----------
    function : callable
        A module-level function (it travels to worker processes by name).
    items : iterable
        The windows, consumed lazily.
    scheduler : str, optional
        See the module docstring.
    args : tuple
        Extra arguments, the same for every item.
    progress : callable, optional
        ``progress(stage, done, total)`` after each result.
    total : int, optional
        Number of items, for the progress.
    stage : str
        The progress's stage name.
    prefetch : bool
        ``synchronous``: take the items through :func:`read_ahead`; ``False`` when
        they are already produced ahead (:func:`read_in_child`).
    prepare : callable, optional
        ``synchronous`` and ``forked``: ``prepare(number)`` is called in the process
        that calibrates item ``number`` (from 0) before it does (e.g. to load compiled
        code from some item on).
    helper : ForkedHelper, optional
        ``forked``: the copy to use, forked earlier (:func:`map_forked`).
    """
    scheduler = check_scheduler(scheduler)
    if scheduler == "auto":
        scheduler = resolve_auto(prefetch)
    if scheduler == "forked" and (helper is not None or child_reading_available()):
        # Forked before any thread of this map starts (read_ahead's).
        helper = ForkedHelper(function, args, prepare) if helper is None else helper
        yield from map_forked(function, read_ahead(items) if prefetch else items, args=args,
                              progress=progress, total=total, stage=stage, prepare=prepare,
                              helper=helper)
        return
    if scheduler in ("synchronous", "forked"):
        for done, item in enumerate(read_ahead(items) if prefetch else items, start=1):
            if prepare is not None:
                prepare(done - 1)
            result = function(item, *args)
            if progress is not None:
                progress(stage, done, total or done)
            yield result
        return
    report = None if progress is None else (lambda done, n: progress(stage, done, n))
    yield from _map_on_dask(function, items, scheduler, args, report, total)


def resolve_auto(prefetch: bool) -> str:
    """What ``auto`` means for a map: ``forked`` when the items come from a forked reader
    (``prefetch`` is then ``False``) on two or more cores, else ``synchronous``."""
    if not prefetch and (os.cpu_count() or 1) >= 2 and child_reading_available():
        return "forked"
    return "synchronous"


#: Items the forked copy of :func:`map_forked` holds at most: the one it calibrates and
#: the next, waiting, so that it never waits for this process between two items.
HELPER_ITEMS = 2


def map_forked(function: Callable[..., Any], items: Iterable[Any], *,
               args: tuple[Any, ...] = (), progress: Progress | None = None,
               total: int | None = None, stage: str = "windows",
               prepare: Callable[[int], None] | None = None,
               helper: ForkedHelper | None = None) -> Iterator[Any]:
    """``function(item, *args)`` for every item, in item order, in two processes: this one
    and a copy of it forked now, each taking the next item when it is free.

    The copy is kept :data:`HELPER_ITEMS` items ahead: it receives each of its items
    pickled over a pipe (a thread of the copy reads them as they come), and this
    process takes an item itself whenever the copy already holds that many.  Neither
    waits for the other, whatever their items' times; at the end this process takes
    back the item the copy has not started (``steal``) and calibrates it.  The copy
    sends back each result with the warnings it raised, raised again here with its
    result; results and exceptions come out in item order (an exception is raised at
    its item, after the results before it).  ``prepare(number)`` runs in the process
    that takes item ``number``, before it.  The copy is forked before the first item
    is asked for (this process's threads, if any, are not in it), or given as
    ``helper`` (made for the same ``function``, ``args`` and ``prepare``), and stopped
    when the iterator is closed, collected, or exhausted.
    """
    helper = ForkedHelper(function, args, prepare) if helper is None else helper
    sent: dict[int, Any] = {}  # items at the copy, by number, until their result is back
    finished: dict[int, tuple[str, Any, list]] = {}
    state = {"next": 0}
    # The registry of the copy's warnings raised again here: one that the filters show
    # once per place is shown once, not once per window.  (This process's own warnings
    # are raised as they come, under the filters' own registries.)
    registry: dict[Any, Any] = {}

    def run_here(number: int, item: Any) -> None:
        if prepare is not None:
            prepare(number)
        try:
            finished[number] = ("result", function(item, *args), [])
        except Exception as exc:  # noqa: BLE001 - raised at its item, in order
            finished[number] = ("error", exc, [])

    def take(message: tuple[str, int, Any, list]) -> None:
        kind, number, payload, notes = message
        item = sent.pop(number)
        if kind == "stolen":
            run_here(number, item)
        else:
            finished[number] = (kind, payload, notes)

    def ready_in_order() -> Iterator[Any]:
        while state["next"] in finished:
            kind, payload, notes = finished.pop(state["next"])
            state["next"] += 1
            for message, category, filename, lineno in notes:
                warnings.warn_explicit(message, category, filename, lineno, registry=registry)
            if kind == "error":
                raise payload
            if progress is not None:
                progress(stage, state["next"], total or state["next"])
            yield payload

    try:
        for number, item in enumerate(items):
            while sent and helper.ready():
                take(helper.receive())
            if len(sent) < HELPER_ITEMS:
                helper.send(number, item)
                sent[number] = item
            else:
                run_here(number, item)
            yield from ready_in_order()
        if len(sent) >= 2:  # one it calibrates and one waiting: the waiting one here
            helper.steal()
        while sent:
            take(helper.receive())
            yield from ready_in_order()
    finally:
        helper.stop()


_END = object()


class ForkedHelper:
    """The forked copy of :func:`map_forked` and its two pipes, forked when made: make it
    before this process starts threads (its copy has none of them)."""

    def __init__(self, function: Callable[..., Any], args: tuple[Any, ...],
                 prepare: Callable[[int], None] | None) -> None:
        import multiprocessing

        context = multiprocessing.get_context("fork")
        self._in_reader, in_writer = context.Pipe(duplex=False)  # helper -> here
        out_reader, self._out_writer = context.Pipe(duplex=False)  # here -> helper
        for connection in (in_writer, self._out_writer):
            _widen_pipe(connection.fileno())
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*fork\(\) may lead to deadlocks",
                                    category=DeprecationWarning)
            self._process = context.Process(
                target=_serve, args=(function, args, prepare, out_reader, in_writer,
                                     self._in_reader, self._out_writer),
                name="graphcal-helper", daemon=True)
            self._process.start()
        out_reader.close()
        in_writer.close()

    def send(self, number: int, item: Any) -> None:
        """Give the copy item ``number`` (it queues it behind those it holds)."""
        import pickle

        self._out_writer.send_bytes(pickle.dumps(("item", number, item),
                                                 protocol=pickle.HIGHEST_PROTOCOL))

    def steal(self) -> None:
        """Ask for the last item the copy holds and has not started: it answers
        ``("stolen", number, None, [])`` (this process then calibrates it), or nothing
        when it has started them all."""
        import pickle

        self._out_writer.send_bytes(pickle.dumps(("steal", -1, None),
                                                 protocol=pickle.HIGHEST_PROTOCOL))

    def ready(self) -> bool:
        """Whether a message of the copy is waiting (:meth:`receive` would not wait)."""
        return bool(self._in_reader.poll())

    def receive(self) -> tuple[str, int, Any, list]:
        """The copy's next message: ``(kind, number, payload, warnings)``, ``kind``
        ``"result"``, ``"error"`` (``payload`` the exception) or ``"stolen"``."""
        import pickle

        try:
            return pickle.loads(self._in_reader.recv_bytes())
        except EOFError:
            self._process.join(timeout=5.0)
            raise RuntimeError(
                f"the helper process stopped (exit code {self._process.exitcode}) before "
                "its window was done; out of memory?") from None

    def stop(self) -> None:
        self._out_writer.close()  # end of file there: the helper returns
        self._in_reader.close()
        self._process.join(timeout=1.0)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join()


def _serve(function: Callable[..., Any], args: tuple[Any, ...],
           prepare: Callable[[int], None] | None, reader: Any, writer: Any,
           *parents_ends: Any) -> None:
    """:class:`ForkedHelper`'s process: each item received, its result (or error) and
    warnings sent back, until the end of the pipe.  A thread receives the items as they
    come (the parent never waits to hand one over) and answers ``steal``."""
    import collections
    import pickle
    import sys

    for connection in parents_ends:
        connection.close()
    signal.signal(signal.SIGTERM, _exit_on_signal)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us
    sys.stdout = open(os.dup(1), "w", closefd=True)  # noqa: SIM115 - for the child's life
    sys.stderr = open(os.dup(2), "w", closefd=True)  # noqa: SIM115
    held: collections.deque[Any] = collections.deque()
    changed = threading.Condition()
    sending = threading.Lock()

    def send(message: tuple[str, int, Any, list]) -> None:
        with sending:
            writer.send_bytes(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))

    def receive() -> None:
        try:
            while True:
                kind, number, item = pickle.loads(reader.recv_bytes())
                with changed:
                    if kind == "item":
                        held.append((number, item))
                        changed.notify()
                        continue
                    stolen = held.pop()[0] if held else None
                if stolen is not None:
                    send(("stolen", stolen, None, []))
        except (EOFError, OSError):
            pass
        with changed:
            held.append(_END)
            changed.notify()

    threading.Thread(target=receive, name="graphcal-helper-inbox", daemon=True).start()
    while True:
        with changed:
            while not held:
                changed.wait()
            if held[0] is _END:
                return
            number, item = held.popleft()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                if prepare is not None:
                    prepare(number)
                message: tuple[str, Any] = ("result", function(item, *args))
            except Exception as exc:  # noqa: BLE001 - handed to the parent
                message = ("error", _travelling(exc))
        notes = [(str(w.message), w.category, w.filename, w.lineno) for w in caught]
        try:
            send((message[0], number, message[1], notes))
        except OSError:
            return


def _map_on_dask(function: Callable[..., Any], items: Iterable[Any], scheduler: str,
                 args: tuple[Any, ...], progress: Progress | None, total: int | None
                 ) -> Iterator[Any]:
    from distributed import wait

    client = _client(scheduler)
    try:
        threads = max(sum(client.nthreads().values()), 1)
        scattered = [client.scatter(a, broadcast=True) for a in args]
        pending: dict[Any, int] = {}
        results: dict[int, Any] = {}
        next_out = done = 0
        for number, item in enumerate(items):
            # The window as scattered data, not inside the task graph (the graph stays
            # small, as Dask wants it).
            data = client.scatter([item], hash=False)[0]
            pending[client.submit(function, data, *scattered, pure=False)] = number
            while len(pending) >= 2 * threads:
                finished, _ = wait(list(pending), return_when="FIRST_COMPLETED")
                for future in finished:
                    results[pending.pop(future)] = future.result()
                    done += 1
                    if progress is not None:
                        progress(done, total or done)
            while next_out in results:
                yield results.pop(next_out)
                next_out += 1
        for future, number in list(pending.items()):
            results[number] = future.result()
            done += 1
            if progress is not None:
                progress(done, total or done)
        while next_out in results:
            yield results.pop(next_out)
            next_out += 1
    finally:
        cluster = getattr(client, "cluster", None)
        client.close()
        if cluster is not None:
            cluster.close()


__all__ = ["SCHEDULERS", "ChildItems", "ForkedHelper", "check_scheduler",
           "child_reading_available", "map_forked", "map_windows", "quiet_large_graphs",
           "read_ahead", "read_in_child", "resolve_auto"]
