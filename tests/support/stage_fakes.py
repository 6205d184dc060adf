"""Fake stages for the runner tests: tiny modules with ``run(ctx)`` installed in place of the
real stage graph (the runner, the registry, the run-folder helpers and the CLI all see them)."""
from __future__ import annotations

import sys
import types

import pipeline.infra.outputs as outputs
import stages.commands.cli as cli
import stages.framework.registry as registry
import stages.framework.runner as runner
from stages.framework.registry import StageSpec


def install(monkeypatch, graph: dict[str, tuple[str, ...]], behaviour: dict | None = None) -> list[str]:
    """Stages named by ``graph`` ({name: upstream names}); ``behaviour[name](ctx)`` runs inside the
    stage after it wrote ``out.txt`` (its name). Returns the list of stage runs, in order."""
    calls: list[str] = []
    behaviour = behaviour or {}
    specs = {}
    for name, ups in graph.items():
        mod = types.ModuleType(f"fake_stage_{name}")

        def run(ctx, name=name):
            calls.append(name)
            (ctx.out / "out.txt").write_text(name)
            if name in behaviour:
                behaviour[name](ctx)
            return f"wrote {name}"
        mod.run = run
        monkeypatch.setitem(sys.modules, mod.__name__, mod)
        specs[name] = StageSpec(name, mod.__name__, tuple(ups), ("features",))
        # whatever a fake stage writes is declared in the catalog (the runner refuses the rest)
        monkeypatch.setitem(outputs.CATALOG, name, {"any": outputs.Artifact("*", "folder", "tests.support.stage_fakes:install", None),
                                                    "files": outputs.Artifact("*", "text", "tests.support.stage_fakes:install", None)})
    for target in (runner, registry, cli):
        monkeypatch.setattr(target, "STAGES", specs)
    monkeypatch.setattr(cli, "ORDER", tuple(specs))
    return calls
