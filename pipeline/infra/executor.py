"""Where independent tasks run: in this process (``local``) or on a Ray cluster (``ray``).

A stage hands an executor a module-level function ``fn(shared, item)``, items and one ``shared``
payload (models, weights, settings). ``map`` returns the results in the items' order, whatever
order the tasks finished in; ``imap`` yields them in that order as they become available, reading
the items lazily (the features stage streams crop batches through it). So outputs do not depend on
the executor or on scheduling, provided ``fn`` derives any randomness from the item itself.

``local`` runs the tasks one after another in this process; each task still uses the threads of
the numerical code inside it (the fusion engine's worker threads, torch's intra-op threads), as
before executors existed. ``ray`` lives in ``pipeline.infra.executor_ray`` and is imported only when
asked for, so the default install does not need Ray.

``gpu=True`` tells the executor a task can use a GPU: Ray then gives each task one GPU where the
cluster has GPUs; ``local`` ignores it (the stage's own device setting applies).
"""
from __future__ import annotations

import time
from typing import Any, Callable, Iterable, Iterator, Protocol, Sequence

from pipeline.infra.device import task_cpus  # noqa: F401 (re-exported: executors' public API)
from pipeline.infra.tasks import STATS, TransientError, item_label, record  # noqa: F401 (re-exported)
from pipeline.infra.executor_ray import RayExecutor
from pipeline.infra.progress import bar as progress_bar

KINDS = ("local", "ray")


class Executor(Protocol):
    name: str

    def map(self, fn: Callable[[Any, Any], Any], items: Sequence[Any], *, shared: Any = None,
            desc: str = "", unit: str = "task", gpu: bool = False) -> list[Any]: ...

    def imap(self, fn: Callable[[Any, Any], Any], items: Iterable[Any], *, shared: Any = None,
             desc: str = "", unit: str = "task", total: int | None = None, gpu: bool = False
             ) -> Iterator[Any]: ...

    def close(self) -> None: ...


class LocalExecutor:
    """Tasks run in order in this process."""
    name = "local"
    gpus = 0

    def imap(self, fn, items, *, shared=None, desc: str = "", unit: str = "task", total=None,
             gpu: bool = False) -> Iterator:
        times: list[float] = []
        with progress_bar(total=total, desc=desc, unit=unit, leave=False) as bar:
            for item in items:
                t = time.perf_counter()
                out = fn(shared, item)
                times.append(time.perf_counter() - t)
                yield out
                bar.update(1)
        # Wall = the tasks alone: the consumer's work between them is not the executor's.
        record(self.name, desc, 1, sum(times), times)

    def map(self, fn, items, *, shared=None, desc: str = "", unit: str = "task", gpu: bool = False) -> list:
        return list(self.imap(fn, items, shared=shared, desc=desc, unit=unit, total=len(items)))

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def make_executor(kind: str = "local", *, address: str = "", workers: int = 0) -> Executor:
    """``local`` or ``ray`` (``address``: empty = start a local Ray instance, ``auto`` or
    ``ray://host:port`` = join a cluster; ``workers``: CPUs for a local instance, 0 = all)."""
    if kind == "local":
        return LocalExecutor()
    if kind == "ray":
        return RayExecutor(address=address, workers=workers)
    raise ValueError(f"unknown executor {kind!r} (known: {', '.join(KINDS)})")


def executor_for(cfg) -> Executor:
    """The executor the config asks for ([run] executor, ray_address, ray_workers)."""
    r = cfg.run
    return make_executor(r.executor, address=r.ray_address, workers=r.ray_workers)
