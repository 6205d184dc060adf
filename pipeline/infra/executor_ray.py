"""The Ray executor: the tasks of one ``map``/``imap`` call run as Ray tasks on a local Ray instance
or on a cluster (``pip install -e '.[ray]'``).

What is sent where: ``shared`` goes into Ray's object store once per call (``ray.put``) and every
task reads it from there (numpy arrays without a copy on the same node); each item travels with
its own task; results come back to this process, in item order. A local instance listens on the
loopback interface only and gets ``workers`` CPUs (0 = every core). Joining a cluster
(``address`` = ``auto`` or ``ray://host:port``) ships this checkout's ``pipeline``, ``loaders``,
``stages`` and ``reports`` packages to the workers (Ray ``py_modules``), so the cluster runs the
same code as the driver; its Python needs this project's dependencies (torch, numpy, ...).

Failures: a worker that dies (out of memory, a lost node) and a task raising ``TransientError``,
``ConnectionError`` or ``TimeoutError`` are retried by Ray up to ``retries`` times; any other
error, or one that keeps coming back, stops the call with ``RuntimeError`` naming the task and
carrying the task's own message. Tasks still running are cancelled.
"""
from __future__ import annotations

import logging
import os
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from pipeline.infra.tasks import TransientError, item_label, record
import pipeline
import pipeline.infra.device as ex
from pipeline.infra.device import available_cores
from pipeline.infra.progress import bar as progress_bar

log = logging.getLogger("viewfuse.executor")

RETRIES = 3
RETRY_ON = (TransientError, ConnectionError, TimeoutError)
PACKAGES = ("pipeline", "loaders", "stages", "reports")
# Ray takes a node's address from the default route; this switch (read at import, hence also set on
# the imported module) makes a new local instance use 127.0.0.1.
_LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def code_root() -> Path:
    """The folder holding the packages this process imported (the checkout, or site-packages)."""

    return Path(pipeline.__file__).resolve().parent.parent


def _run_task(fn: Callable[[Any, Any], Any], shared: Any, item: Any, cpus: int) -> Any:
    """Runs inside a Ray worker: (``fn(shared, item)``, seconds it took), ``task_cpus()`` telling
    ``fn`` its CPUs."""

    ex._TASK_CPUS = cpus
    t0 = time.perf_counter()
    try:
        return fn(shared, item), time.perf_counter() - t0
    finally:
        ex._TASK_CPUS = 0


def _import_ray():
    try:
        import ray
    except ImportError:
        raise RuntimeError("run.executor = 'ray' needs Ray: pip install -e '.[ray]' (or make venv-ray)") from None
    return ray


@contextmanager
def _loopback():
    """While a local instance starts: its processes (which inherit the environment) bind to
    127.0.0.1. Restored afterwards, so a later cluster connection in this process is unaffected."""
    from ray._private import ray_constants

    old_env, old = os.environ.get(_LOOPBACK_ENV), ray_constants.ENABLE_RAY_CLUSTER
    os.environ[_LOOPBACK_ENV] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = old
        if old_env is None:
            os.environ.pop(_LOOPBACK_ENV, None)
        else:
            os.environ[_LOOPBACK_ENV] = old_env


class RayExecutor:
    """Tasks as Ray tasks; results in item order; one progress bar over the tasks."""
    name = "ray"

    def __init__(self, address: str = "", workers: int = 0, *, retries: int = RETRIES, cpus_per_task: int = 1):
        ray = _import_ray()
        self._ray = ray
        self.retries = int(retries)
        self.cpus_per_task = max(1, int(cpus_per_task))
        self._started = False
        if not ray.is_initialized():
            kw: dict[str, Any] = dict(include_dashboard=False, configure_logging=False, log_to_driver=True)
            if address:
                mods = [str(code_root() / p) for p in PACKAGES if (code_root() / p).is_dir()]
                ray.init(address=address, runtime_env={"py_modules": mods}, **kw)
            else:
                # Workers import the same checkout as this process, whatever is installed.
                path = os.pathsep.join(p for p in (str(code_root()), os.environ.get("PYTHONPATH", "")) if p)
                with _loopback():
                    ray.init(address="local", num_cpus=int(workers) or available_cores(),
                             runtime_env={"env_vars": {"PYTHONPATH": path}}, **kw)
                self._check_loopback()
            self._started = True
        res = ray.cluster_resources()
        self.cpus = int(res.get("CPU", 0))
        self.gpus = int(res.get("GPU", 0))
        self._fn = ray.remote(_run_task)
        log.info("Ray: %s, %d CPUs, %d GPUs", address or "local instance", self.cpus, self.gpus)

    def _check_loopback(self) -> None:
        addr = self._ray.util.get_node_ip_address()
        if addr not in ("127.0.0.1", "::1"):
            log.warning("local Ray instance listens on %s, not only on the loopback interface", addr)

    @property
    def node_address(self) -> str:
        return self._ray.util.get_node_ip_address()

    def slots(self, gpu: bool = False) -> int:
        """Tasks that can run at once."""
        if gpu and self.gpus:
            return self.gpus
        return max(1, self.cpus // self.cpus_per_task)

    def _remote(self, gpu: bool):
        use_gpu = bool(gpu and self.gpus)
        return self._fn.options(num_cpus=self.cpus_per_task, num_gpus=1 if use_gpu else 0,
                                max_retries=self.retries, retry_exceptions=list(RETRY_ON))

    def imap(self, fn, items: Iterable, *, shared=None, desc: str = "", unit: str = "task",
             total: int | None = None, gpu: bool = False, window: int = 0) -> Iterator:
        """Results in item order. At most ``window`` tasks (default twice the slots) are submitted
        and not yet yielded, so items are read as the cluster keeps up."""

        ray = self._ray
        what = desc or getattr(fn, "__name__", "task")
        shared_ref = ray.put(shared)
        remote = self._remote(gpu)
        window = int(window) or 2 * self.slots(gpu)
        source = enumerate(items)
        inflight: dict = {}            # ObjectRef -> (index, label)
        ready: dict[int, Any] = {}     # finished, waiting for the earlier ones
        nxt, exhausted = 0, False
        t0, times = time.perf_counter(), []
        bar = progress_bar(total=total, desc=desc, unit=unit, leave=False)
        try:
            while True:
                while not exhausted and len(inflight) + len(ready) < window:
                    try:
                        i, item = next(source)
                    except StopIteration:
                        exhausted = True
                        break
                    inflight[remote.remote(fn, shared_ref, item, self.cpus_per_task)] = (i, item_label(item))
                while nxt in ready:
                    yield ready.pop(nxt)
                    nxt += 1
                if not inflight:
                    if exhausted and not ready:
                        record(self.name, desc, self.slots(gpu), time.perf_counter() - t0, times)
                        return
                    continue
                done, _ = ray.wait(list(inflight), num_returns=1)
                rest = [r for r in inflight if r not in done]
                more = ray.wait(rest, num_returns=len(rest), timeout=0)[0] if rest else []
                for ref in done + more:
                    i, label = inflight.pop(ref)
                    ready[i], took = self._get(ref, i, total, label, what)
                    times.append(took)
                    bar.update(1)
        finally:
            bar.close()
            for ref in inflight:
                ray.cancel(ref)

    def map(self, fn, items, *, shared=None, desc: str = "", unit: str = "task", gpu: bool = False) -> list:
        items = list(items)
        return list(self.imap(fn, items, shared=shared, desc=desc, unit=unit, total=len(items), gpu=gpu))

    def _get(self, ref, i: int, total: int | None, label: str, what: str) -> Any:
        ray = self._ray
        where = f"{what}: task {i + 1}{f' of {total}' if total else ''} ({label})"
        try:
            return ray.get(ref)
        except ray.exceptions.RayTaskError as err:
            cause = getattr(err, "cause", None)
            if not isinstance(cause, BaseException):
                raise RuntimeError(f"{where} failed on Ray: {err}") from None
            tries = f" (after {self.retries} retries)" if isinstance(cause, RETRY_ON) else ""
            raise RuntimeError(f"{where} failed{tries}: {type(cause).__name__}: {cause}") from cause
        except ray.exceptions.RayError as err:
            # A worker or node that kept dying, an object lost with its node, a cancelled task.
            raise RuntimeError(f"{where} failed on Ray (retried up to {self.retries} times): {err}") from None

    def close(self) -> None:
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()
        self._started = False

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
