"""Where independent tasks run: in this process (``local``) or on a Ray cluster (``ray``).

A stage hands an executor a module-level function ``fn(shared, item)``, a list of items and one
``shared`` payload (models, settings). ``map`` returns the results in the items' order, whatever
order the tasks finished in, so outputs do not depend on the executor or on scheduling.

``local`` runs the tasks one after another in this process; each task still uses the threads of
the numerical code inside it (the fusion engine's worker threads, torch's intra-op threads), as
before executors existed. ``ray`` lives in ``pipeline.executor_ray`` and is imported only when
asked for, so the default install does not need Ray.
"""
from __future__ import annotations

from typing import Any, Callable, Protocol, Sequence

KINDS = ("local", "ray")


class Executor(Protocol):
    name: str

    def map(self, fn: Callable[[Any, Any], Any], items: Sequence[Any], *, shared: Any = None,
            desc: str = "", unit: str = "task") -> list[Any]: ...

    def close(self) -> None: ...


class LocalExecutor:
    """Tasks run in order in this process."""
    name = "local"

    def map(self, fn, items, *, shared=None, desc: str = "", unit: str = "task") -> list:
        from pipeline.progress import bar as progress_bar

        out = []
        with progress_bar(total=len(items), desc=desc, unit=unit, leave=False) as bar:
            for item in items:
                out.append(fn(shared, item))
                bar.update(1)
        return out

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
        from pipeline.executor_ray import RayExecutor  # optional extra: pip install -e '.[ray]'
        return RayExecutor(address=address, workers=workers)
    raise ValueError(f"unknown executor {kind!r} (known: {', '.join(KINDS)})")
