"""Where the independent per-view / per-image / per-pair-chunk / per-method tasks run.

Three modes, one API (:meth:`Executor.map`: apply a module-level function to small, picklable
task records and return the small result records in input order):

* ``serial`` (default): in this process, one task after the other, exactly as without this
  module (no Dask import).
* ``local`` (``--workers N``): a ``dask.distributed.LocalCluster`` of N worker processes with
  one thread each on this machine.
* ``remote`` (``--scheduler ADDRESS`` or ``$POLARREF_SCHEDULER``): an existing cluster
  (``dask scheduler`` + ``dask worker``, dask-jobqueue, ...). Workers must see the same
  folders under the same paths (shared filesystem): tasks exchange files, not arrays.

Tasks write their outputs with atomic renames, so a task lost with its worker is simply run
again by the scheduler (Dask reschedules tasks of a dead worker, up to
``distributed.scheduler.allowed-failures`` times). Exceptions inside a task are not retried:
they are real errors (bad input) and reach the caller as raised.

Inside a worker every task runs with BLAS, OpenMP and OpenCV limited to one thread, so N workers
use N cores and results do not depend on thread counts.
"""

from __future__ import annotations

import atexit
import functools
import logging
import os
import socket
import uuid
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable, Iterator, Sequence, TypeVar

from polarref.core.errors import PolarrefError
from polarref.core.progress import track

log = logging.getLogger(__name__)

ENV_SCHEDULER = "POLARREF_SCHEDULER"
CONNECT_TIMEOUT_S = 5.0   # an unreachable scheduler fails fast, with its address in the message
WAIT_WORKERS_S = 30.0     # a reachable scheduler without any worker would otherwise hang forever
# Set in worker processes before numpy/OpenCV load (LocalCluster) and again per task.
THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

T = TypeVar("T")
R = TypeVar("R")


@dataclass(frozen=True)
class ExecutionSpec:
    """Which executor to build: mode ``serial`` | ``local`` | ``remote``."""

    mode: str = "serial"
    workers: int = 0             # local: number of worker processes
    address: str | None = None   # remote: scheduler address, e.g. tcp://10.0.0.5:8786


def resolve(workers: int | None = None, scheduler: str | None = None,
            environ: dict | None = None) -> ExecutionSpec:
    """The spec from the CLI options; ``$POLARREF_SCHEDULER`` applies when neither is given."""
    env = os.environ if environ is None else environ
    if workers and scheduler:
        raise PolarrefError("local workers and a scheduler address exclude each other")
    if workers is not None and workers < 1:
        raise PolarrefError(f"the number of workers must be >= 1, got {workers}", option="workers")
    if workers:
        cores = available_cores()
        if workers > cores:
            # one single-threaded process per core is the most this machine can use; ~1,000
            # processes on 2 cores stalled it for minutes
            log.warning("%d workers requested on %d available core(s): using %d", workers, cores, cores)
            workers = cores
        return ExecutionSpec("local", workers=int(workers))
    address = scheduler or env.get(ENV_SCHEDULER, "").strip() or None
    return ExecutionSpec("remote", address=address) if address else ExecutionSpec()


@dataclass(frozen=True)
class WorkerInfo:
    """One Dask worker as the scheduler sees it."""

    address: str
    host: str
    pid: int | None
    nthreads: int
    memory_limit_bytes: int


@dataclass
class Description:
    """What ``polarref doctor`` prints about execution."""

    mode: str
    detail: str
    workers: list[WorkerInfo] = field(default_factory=list)
    dashboard: str | None = None


class SerialExecutor:
    """Run every task here, in order (the default)."""

    in_process = True
    spec = ExecutionSpec()

    def map(self, fn: Callable[[T], R], items: Sequence[T], *, desc: str = "tasks") -> list[R]:
        return [fn(x) for x in track(items, desc=desc, total=len(items))]

    def size(self) -> int:
        return 1

    def describe(self) -> Description:
        return Description("serial", "in this process, one task at a time (no Dask)")

    def close(self) -> None:
        pass


def _connect_error(address: str, exc: BaseException) -> PolarrefError:
    reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return PolarrefError(f"cannot reach the Dask scheduler at {address} ({reason}); "
                         f"start it with `dask scheduler` or fix --scheduler/${ENV_SCHEDULER}")


@contextmanager
def _quiet_dask() -> Iterator[None]:
    """Dask logs every failed connection attempt; the caller reports one line instead."""
    names = [n for n in logging.root.manager.loggerDict if n.split(".")[0] == "distributed"]
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio", *names)]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for lg, lv in zip(loggers, levels):
            lg.setLevel(lv)


class DaskExecutor:
    """Run tasks on a Dask cluster (a LocalCluster started here, or an existing scheduler)."""

    in_process = False

    def __init__(self, spec: ExecutionSpec):
        import dask
        from distributed import Client, LocalCluster

        self.spec = spec
        self.cluster = None
        if spec.mode == "local":
            # Workers are not daemonic so that a compare method running in a worker can still
            # start its own isolated child process (polarref.core.isolated).
            with dask.config.set({"distributed.worker.daemon": False}), _quiet_dask():
                self.cluster = LocalCluster(n_workers=spec.workers, threads_per_worker=1, processes=True,
                                            dashboard_address=":0", env=dict(THREAD_ENV),
                                            silence_logs=logging.ERROR)
                self.client = Client(self.cluster, timeout=CONNECT_TIMEOUT_S * 6)
        elif spec.mode == "remote":
            try:
                with _quiet_dask():
                    self.client = Client(spec.address, timeout=CONNECT_TIMEOUT_S)
            except (OSError, TimeoutError, ValueError) as exc:
                raise _connect_error(str(spec.address), exc) from None
            try:
                self.client.wait_for_workers(1, timeout=WAIT_WORKERS_S)
            except (TimeoutError, OSError):
                self.close()
                raise PolarrefError(f"the Dask scheduler at {spec.address} has no workers after "
                                    f"{WAIT_WORKERS_S:g} s; start some with `dask worker {spec.address}`") from None
        else:
            raise ValueError(f"DaskExecutor needs mode local or remote, not {spec.mode!r}")

    def map(self, fn: Callable[[T], R], items: Sequence[T], *, desc: str = "tasks") -> list[R]:
        from distributed import KilledWorker, as_completed
        from distributed.comm.core import CommClosedError

        if not items:
            return []
        batch = uuid.uuid4().hex  # unique keys: equal keys would share one result on the scheduler
        futures = self.client.map(functools.partial(_in_worker, fn), list(items), pure=False,
                                  key=[f"{desc}-{batch}-{i}" for i in range(len(items))])
        try:
            for fut in track(as_completed(futures), desc=desc, total=len(futures)):
                if fut.status == "error":
                    fut.result()  # raises the task's own exception here
            return [f.result() for f in futures]
        except KilledWorker as exc:
            self._cancel(futures)
            raise PolarrefError(f"{desc}: a task was lost with every worker that ran it ({exc}); the workers "
                                f"may run out of memory or be killed: see their logs") from None
        except CommClosedError:
            self._cancel(futures)
            raise PolarrefError(f"{desc}: lost the connection to the Dask scheduler "
                                f"{self.spec.address or '(local)'}") from None
        except BaseException:
            self._cancel(futures)
            raise

    def _cancel(self, futures) -> None:
        try:
            self.client.cancel(futures)
        except Exception:  # the scheduler may be gone; the error being raised matters more
            pass

    def size(self) -> int:
        """Number of workers now (chunking hint only: results never depend on it)."""
        return max(1, len(self.client.nthreads()))

    def workers(self) -> list[WorkerInfo]:
        info = self.client.scheduler_info(n_workers=-1) if _accepts_n_workers(self.client) \
            else self.client.scheduler_info()
        pids = self.client.run(os.getpid)
        out = []
        for addr, w in sorted(info.get("workers", {}).items()):
            out.append(WorkerInfo(addr, str(w.get("host", "")), pids.get(addr), int(w.get("nthreads", 0)),
                                  int(w.get("memory_limit", 0))))
        return out

    def describe(self) -> Description:
        where = (f"LocalCluster of {self.spec.workers} worker processes x 1 thread on this machine"
                 if self.spec.mode == "local" else f"Dask scheduler at {self.spec.address}")
        return Description(self.spec.mode, where, self.workers(), getattr(self.client, "dashboard_link", None))

    def close(self) -> None:
        with _quiet_dask():
            try:
                self.client.close()
            finally:
                if self.cluster is not None:
                    self.cluster.close()


def _accepts_n_workers(client) -> bool:
    import inspect

    return "n_workers" in inspect.signature(client.scheduler_info).parameters


# ---- inside a worker ---------------------------------------------------------------------------
_WORKER_READY = False


def on_worker() -> bool:
    """True inside a Dask worker's task."""
    try:
        from distributed import get_worker
    except ImportError:
        return False
    try:
        get_worker()
    except ValueError:
        return False
    return True


def _prepare_worker() -> None:
    """Once per worker process: one thread for BLAS, OpenMP and OpenCV."""
    global _WORKER_READY
    if _WORKER_READY:
        return
    os.environ.update(THREAD_ENV)
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)  # persistent: not used as a context manager
    import cv2

    cv2.setNumThreads(1)
    _WORKER_READY = True


def _in_worker(fn: Callable[[T], R], item: T) -> R:
    _prepare_worker()
    return fn(item)


# ---- the executor of this process --------------------------------------------------------------
_SPEC = ExecutionSpec()
_CURRENT: SerialExecutor | DaskExecutor | None = None


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity, else the machine's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def check_reachable(spec: ExecutionSpec) -> None:
    """A remote scheduler's address is parsed and its port connected to (one TCP connect,
    CONNECT_TIMEOUT_S) before any work: a typo then fails before an output folder exists."""
    if spec.mode != "remote" or not spec.address:
        return
    text = spec.address.split("://", 1)[-1]
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 < int(port) < 65536:
        raise PolarrefError(f"scheduler address {spec.address!r} is not HOST:PORT or tcp://HOST:PORT "
                            f"(fix --scheduler/${ENV_SCHEDULER})")
    try:
        socket.create_connection((host.strip("[]") or "localhost", int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise _connect_error(spec.address, exc) from None


def configure(workers: int | None = None, scheduler: str | None = None) -> ExecutionSpec:
    """Choose the executor (the CLI calls this once); it is started on first use."""
    global _SPEC
    shutdown()
    _SPEC = resolve(workers, scheduler)
    return _SPEC


def current() -> SerialExecutor | DaskExecutor:
    """The executor chosen by :func:`configure`; serial inside a worker (no nested clusters)."""
    global _CURRENT
    if _SPEC.mode == "serial" or on_worker():
        return _SERIAL
    if _CURRENT is None:
        _CURRENT = DaskExecutor(_SPEC)
        # Registered after distributed's own exit hooks, so it runs before them (quietly).
        atexit.register(shutdown)
    return _CURRENT


def shutdown() -> None:
    """Close the cluster/client started by :func:`current` (also at interpreter exit)."""
    global _CURRENT
    if _CURRENT is not None:
        ex, _CURRENT = _CURRENT, None
        ex.close()


@contextmanager
def using(workers: int | None = None, scheduler: str | None = None) -> Iterator[SerialExecutor | DaskExecutor]:
    """Library/test use: ``with using(workers=2) as ex: render_scene(...)``.

    Nests: the executor chosen outside is kept (not closed) and is the current one again after.
    """
    global _SPEC, _CURRENT
    saved = (_SPEC, _CURRENT)
    _SPEC, _CURRENT = resolve(workers, scheduler, environ={}), None
    try:
        yield current()
    finally:
        shutdown()
        _SPEC, _CURRENT = saved


_SERIAL = SerialExecutor()
