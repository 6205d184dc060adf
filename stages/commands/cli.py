"""``viewfuse <stage>``: run one pipeline stage (and whatever it needs that is stale);
``viewfuse status``: what is up to date, stale (and why) or missing, without running anything."""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import errno
import json
import logging
import os
import signal
import sys
import threading
import traceback
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from pipeline.infra.config import Config, ConfigError, load_config, merge, parse_override
from pipeline.infra.config.own import own_items, registered as own_key_of
from pipeline.infra.config.schema import json_schema
from stages.framework.registry import ORDER, STAGES
from stages.framework.checkout import other_checkout
from pipeline.evaluation.metrics.spec import check_primary
from pipeline.scoring.classifiers import check_config
from stages.framework.runner import plan
from pipeline.infra.workers import raise_on_sigterm
from pipeline.infra.workers import Terminated
from pipeline.infra import progress
from stages.framework.runner import ensure, remove_orphans
from stages.commands.compare import run as compare_runs
from stages.commands.study import run_study
from stages.framework import stage_cache
from stages.framework.runner import read_manifest

DEFAULT_CONFIG = "configs/synthetic.toml"


def version() -> str:
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version
    try:
        return dist_version("viewfuse")
    except PackageNotFoundError:  # run from a checkout without installing
        return "unknown (not installed)"


def config_keys_help(section: str) -> str:
    """One line per config key a stage reads: a section (nested sections dotted) or, dotted, one
    key (``evaluate.targets``); each with its default, range or choices and its doc."""
    lines: list[str] = []

    def line(f: dataclasses.Field, value, name: str) -> str:
        md = f.metadata
        rng = ""
        if md.get("choices"):
            rng = " one of " + "|".join(map(str, md["choices"]))
        elif md.get("lo") is not None or md.get("hi") is not None:
            lo, hi = md.get("lo"), md.get("hi")
            rng = f" in [{'' if lo is None else lo}, {'' if hi is None else hi}]"
        doc = f": {md['doc']}" if md.get("doc") else ""
        shown = list(value) if isinstance(value, tuple) else value
        return f"  {name} = {shown!r}{rng}{doc}"

    def walk(obj, prefix: str) -> None:
        for f in dataclasses.fields(obj):
            if f.metadata.get("internal"):
                continue
            value = getattr(obj, f.name)
            if dataclasses.is_dataclass(value):
                walk(value, f"{prefix}{f.name}.")
            else:
                lines.append(line(f, value, prefix + f.name))
        for name, value in own_items(obj):   # the sections (and keys) extensions declared under this one
            if dataclasses.is_dataclass(value):
                walk(value, f"{prefix}{name}.")
            else:
                lines.append(line(own_key_of(prefix[:-1])[name].field, value, prefix + name))

    parent_path, _, last = section.rpartition(".")
    parent = Config().section(parent_path) if parent_path else Config()
    value = getattr(parent, last)
    if dataclasses.is_dataclass(value):
        walk(value, f"{section}.")
    else:
        f = next((f for f in dataclasses.fields(parent) if f.name == last), None)
        lines.append(line(f if f is not None else own_key_of(parent_path)[last].field, value, section))
    return "\n".join(lines)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default=DEFAULT_CONFIG, help=f"TOML config (default: {DEFAULT_CONFIG})")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. --set evaluate.randomized.realizations=50")
    p.add_argument("--progress", choices=("auto", "on", "off"), default="auto",
                   help="progress bars: auto = on a terminal only (a log gets a few plain lines), "
                        "on = always, off = none")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    p.add_argument("--debug", action="store_true",
                   help="on an error, print the Python traceback too (errors are otherwise one line)")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="viewfuse",
        description="Spatially-dependent Bayesian semantic perception: BigBIRD-trained viewpoint "
                    "GP class models, fused along an AVD track under model and localization "
                    "uncertainty. Each stage reruns its stale upstream stages first and is skipped "
                    "when its manifest is up to date (same config, code, upstream outputs and "
                    "input files). 'viewfuse <stage> --help' lists that stage's config keys.",
        epilog="stages: " + "; ".join(f"{n}: {STAGES[n].help}" for n in ORDER),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"viewfuse {version()}")
    sub = p.add_subparsers(dest="stage", metavar="STAGE", required=True)
    for name in ORDER:
        spec = STAGES[name]
        keys = "config keys this stage reads:\n" + "\n".join(config_keys_help(s) for s in spec.sections)
        sp = sub.add_parser(name, help=spec.help, description=f"{name}: {spec.help}. Needs: "
                            f"{', '.join(spec.upstream) or 'nothing upstream'}.", epilog=keys,
                            formatter_class=argparse.RawDescriptionHelpFormatter)
        _common(sp)
        sp.add_argument("--force", action="store_true", help="rerun this stage even if its manifest is up to date")
        sp.add_argument("--device", choices=("auto", "cpu", "cuda"), default=None,
                        help="torch device (default: config run.device; auto = cuda when present)")
        sp.add_argument("--threads", type=int, default=None,
                        help="torch threads, 0..256 like run.threads (default: config run.threads; 0 = all cores)")
        sp.add_argument("--executor", choices=("local", "ray"), default=None,
                        help="where features and evaluate run their tasks (default: config run.executor; "
                             "ray: local Ray instance, or the cluster in run.ray_address)")
    st = sub.add_parser("status", help="each stage: up to date, stale (and why) or missing; runs nothing",
                        description="Show, for every stage, whether its outputs are up to date for the "
                                    "config, code and inputs, stale (with the reason) or missing.")
    _common(st)
    sy = sub.add_parser("study", help="seed study: classifier -> evaluate once per study.seeds classifier seed",
                        description="Rerun classifier, features, models and evaluate for every seed of "
                                    "study.seeds under <run>/study/seed-<n>/ (finished seeds are reused), "
                                    "then write study/index.html and study/summary.json side by side.")
    _common(sy)
    sy.add_argument("--force", action="store_true", help="rerun each seed's evaluate stage")
    cp = sub.add_parser("compare", help="finished runs side by side: config keys that differ, pooled metrics, verdicts",
                        description="Compare finished runs (run folders, or folders of runs such as "
                                    "<run>/study/: a seed group pooled over its seeds). Reads only each run's "
                                    "evaluate/summary.json and stage manifests; prints a table and writes "
                                    "an HTML page.")
    cp.add_argument("runs", nargs="+", metavar="RUN_OR_DIR", help="artifacts/<run> or a folder of run folders")
    cp.add_argument("--out", default=None, help="folder for index.html (default: <first run>/compare)")
    cp.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    cp.add_argument("--debug", action="store_true", help="on an error, print the Python traceback too")
    sc = sub.add_parser("schema", help="a JSON Schema of the config file, for editors (stdout or --out)",
                        description="Write a JSON Schema of the config file from the declarations the loader "
                                    "checks (types, ranges, choices, docs, registered sections).")
    sc.add_argument("--out", default=None, help="file to write (default: stdout)")
    sc.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sc.add_argument("--debug", action="store_true", help="on an error, print the Python traceback too")
    return p


def _load(args) -> Config:
    foreign = other_checkout()
    if foreign:
        logging.getLogger("viewfuse").warning("%s", foreign)
    overrides: dict = {}
    for o in args.overrides:
        overrides = merge(overrides, parse_override(o))
    # --device/--threads are config values given on the command line: validated the same way.
    if getattr(args, "device", None) is not None:
        overrides = merge(overrides, {"run": {"device": args.device}})
    if getattr(args, "threads", None) is not None:
        overrides = merge(overrides, {"run": {"threads": args.threads}})
    if getattr(args, "executor", None) is not None:
        overrides = merge(overrides, {"run": {"executor": args.executor}})
    cfg = load_config(args.config, overrides or None)

    # The checks that live above the config's floor (the arch's own, in the classifier registry;
    # metric names, with the metrics), run here at load so `status` refuses as the stages would.
    _checked(args, cfg, "classifier.", lambda c: check_config(c.classifier, ""))
    _checked(args, cfg, "evaluate.primary_metrics", lambda c: check_primary(c.evaluate.primary_metrics))
    return cfg


def _checked(args, cfg: Config, prefix: str, check) -> None:
    """Run ``check(cfg)``; its ConfigError names where the keys came from: ``--set`` when an
    override sets a key under ``prefix`` and the file alone passes the check, else the file."""
    try:
        check(cfg)
    except ConfigError as e:
        msg = str(e).removeprefix(": ")
        src = str(args.config)
        if any(o.split("=", 1)[0].strip().startswith(prefix) for o in args.overrides):
            try:
                check(load_config(args.config))
                src = f"--set on the command line (over {args.config})"
            except ConfigError:
                pass
        raise ConfigError(f"{src}: {msg}") from None


def status(cfg: Config) -> int:
    """The status table on stdout; exit 1 when a stage's state cannot be determined."""
    print(f"run folder: {cfg.run_dir}", file=sys.stderr)
    memo: dict = {}
    width = max(map(len, ORDER))
    rc = 0
    for name in ORDER:
        try:
            s = plan(cfg, name, memo)
            line = s["state"] + (f": {s['why']}" if s["state"] == "stale" else "") + _cache_words(cfg, name, s)
        except (OSError, ValueError) as e:
            line = f"unknown: {describe(e)}"
            rc = 1
        print(f"{name:<{width}}  {line}")
    return rc


def _cache_words(cfg: Config, name: str, s: dict) -> str:
    """What the stage cache says of a stage: the run an up-to-date stage's outputs came from, or
    the run whose outputs a stale or missing stage will reuse."""

    if s["state"] == "up to date":
        r = (read_manifest(cfg, name) or {}).get("reused")
        return f" (reused from run {r['run']!r} through the stage cache)" if r else ""
    hit = stage_cache.find(cfg, name, s["key"]) if s.get("key") else None
    return f" (the stage cache holds it from run {hit['run']!r}: it will be reused)" if hit else ""


# errno -> what it means for a run, in words
_ERRNO_WORDS = {
    errno.ENOSPC: "no space left on the device (the disk is full)",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.ENOENT: "no such file or folder",
    errno.EISDIR: "is a folder, not a file",
    errno.ENOTDIR: "a part of the path is not a folder",
    errno.EMFILE: "too many open files",
    errno.EIO: "input/output error (failing disk or network file system)",
    errno.ENAMETOOLONG: "file name too long",
}


def describe(e: BaseException) -> str:
    """One line for an expected failure: the file or key and the problem."""
    if isinstance(e, OSError) and e.errno is not None:
        words = _ERRNO_WORDS.get(e.errno, e.strerror or str(e))
        code = errno.errorcode.get(e.errno, str(e.errno))
        where = "".join(f"{f}: " for f in (e.filename, e.filename2) if f)
        return f"{where}{words} ({code})"
    if isinstance(e, UnicodeDecodeError):
        return f"cannot decode text as {e.encoding} (byte {e.start}): {e.reason}"
    if isinstance(e, KeyError) and e.args:
        return str(e.args[0])
    return str(e) or type(e).__name__


UNGUARDED = ("viewfuse: main() was called while a worker process re-imported the launcher script {file} "
             "(stage worker pools start processes that import the script that started the run, as "
             "'__mp_main__'): call main() only under `if __name__ == \"__main__\":` (docs/api.md, the launcher)")


def _reimported_launcher() -> str | None:
    """The file of the script this worker process is re-importing when ``main()`` is called from
    its top level (a launcher without the ``__main__`` guard), else None. A spawned worker imports
    the parent's main script as ``__mp_main__``; run there, ``main()`` would start the stage again
    and wait forever on the lock its parent holds. (``multiprocessing.parent_process()`` is not
    set yet while the worker imports the script: the module frame tells.)"""
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_globals.get("__name__") == "__mp_main__" and frame.f_code.co_name == "<module>":
            return frame.f_globals.get("__file__", "?")
        frame = frame.f_back
    return None


def main(argv: list[str] | None = None) -> int:
    """The error boundary: every failure ends in one line on stderr (the traceback too with
    --debug). Exit codes: 0 done, 1 a runtime error, 2 a config error, 130 interrupted, 141 stdout
    closed early (``viewfuse status | head -1``), 143 terminated (SIGTERM).

    Called without ``argv`` (a program: the ``viewfuse`` command, a launcher script) it exits
    with the code; with ``argv`` it returns it. In a worker process re-importing a launcher that
    lacks the ``__main__`` guard it refuses at once (exit 2) instead of running the stage again."""
    launcher = _reimported_launcher()
    if launcher is not None:
        print(UNGUARDED.format(file=launcher), file=sys.stderr)
        raise SystemExit(2)
    if argv is None:
        raise SystemExit(_run(None))
    return _run(argv)


def _run(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    where = f"viewfuse {args.stage}"

    main_thread = threading.current_thread() is threading.main_thread()
    before = signal.getsignal(signal.SIGTERM) if main_thread else None
    if main_thread:
        raise_on_sigterm()  # SIGTERM cleans up as Ctrl-C does: pools stopped, partial outputs removed
    try:
        return _boundary(args, where)
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, before)


def _boundary(args, where: str) -> int:
    try:
        rc = _main(args)
        sys.stdout.flush()  # a closed pipe shows here, inside the boundary, not at exit
        return rc
    except BrokenPipeError:
        # The reader went away: stop quietly, and keep Python from complaining at exit.
        with contextlib.suppress(OSError, ValueError):
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        return 141
    except KeyboardInterrupt as e:
        how = "terminated (SIGTERM)" if isinstance(e, Terminated) else "interrupted"
        print(f"{where}: {how}; partial outputs were discarded", file=sys.stderr)
        return 143 if isinstance(e, Terminated) else 130
    except Exception as e:  # noqa: BLE001 - the boundary: nothing escapes as a raw traceback
        if args.debug:
            traceback.print_exc()
        if isinstance(e, ConfigError):
            print(f"{where}: config error: {describe(e)}", file=sys.stderr)
            return 2
        expected = isinstance(e, (OSError, ValueError, RuntimeError, KeyError))
        hint = "" if expected or args.debug else " (an internal error: rerun with --debug for the traceback)"
        if isinstance(e, BrokenProcessPool) and "killed by" not in str(e):
            # a worker that exits on its own while starting is what a launcher without the guard makes
            hint = (" (a worker process ended early: any message it printed is above; a launcher script "
                    "must call main() under `if __name__ == \"__main__\":`, docs/api.md)")
        kind = "" if expected else f"{type(e).__name__}: "
        print(f"{where}: error: {kind}{describe(e)}{hint}", file=sys.stderr)
        return 1


def _main(args) -> int:
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    if args.stage == "compare":  # not a stage: reads finished runs only (stages/commands/compare.py)
        return compare_runs(args.runs, args.out)
    if args.stage == "schema":   # not a stage: the config's declarations as a JSON Schema
        text = json.dumps(json_schema(), indent=1, ensure_ascii=False) + "\n"
        if args.out:
            Path(args.out).write_text(text)
        else:
            sys.stdout.write(text)
        return 0
    progress.set_mode(args.progress)
    cfg = _load(args)
    if args.stage == "status":
        return status(cfg)
    print(f"run folder: {cfg.run_dir}", file=sys.stderr)
    with progress.redirect_logging():
        remove_orphans(cfg)
        if args.stage == "study":  # not a stage: the chain once per seed (stages/commands/study.py)
            run_study(cfg, device=cfg.run.device, threads=cfg.run.threads, force=args.force)
            return 0
        keys: dict[str, str] = {}
        ensure(cfg, args.stage, force=args.force, device=cfg.run.device, threads=cfg.run.threads, _keys=keys)
        for after in STAGES[args.stage].after:
            ensure(cfg, after, device=cfg.run.device, threads=cfg.run.threads, _keys=keys)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
