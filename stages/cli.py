"""``viewfuse <stage>``: run one pipeline stage (and whatever it needs that is stale)."""
from __future__ import annotations

import argparse
import logging
import sys

from pipeline.config import ConfigError, load_config, parse_override, _merge
from stages.registry import ORDER, STAGES
from stages.runner import StageNotImplemented, ensure

DEFAULT_CONFIG = "configs/synthetic.toml"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="viewfuse",
        description="Spatially-dependent Bayesian semantic perception: BigBIRD-trained viewpoint "
                    "GP class models, fused along an AVD track under model and localization "
                    "uncertainty. Each stage reruns its stale upstream stages first and is skipped "
                    "when its manifest is up to date.",
        epilog="stages: " + "; ".join(f"{n}: {STAGES[n].help}" for n in ORDER),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("stage", choices=ORDER, help="stage to run")
    p.add_argument("--config", default=DEFAULT_CONFIG, help=f"TOML config (default: {DEFAULT_CONFIG})")
    p.add_argument("--force", action="store_true", help="rerun this stage even if its manifest is up to date")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default=None,
                   help="torch device (default: config run.device; auto = cuda when present)")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: config run.threads; 0 = all cores)")
    p.add_argument("--executor", choices=("local", "ray"), default=None,
                   help="where features and evaluate run their tasks (default: config run.executor; "
                        "ray: local Ray instance, or the cluster in run.ray_address)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. --set evaluate.randomized.realizations=50")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        overrides: dict = {}
        for o in args.overrides:
            overrides = _merge(overrides, parse_override(o))
        if args.executor:
            overrides = _merge(overrides, {"run": {"executor": args.executor}})
        cfg = load_config(args.config, overrides or None)
    except ConfigError as e:
        print(f"viewfuse: config error: {e}", file=sys.stderr)
        return 2
    device = args.device or cfg.run.device
    threads = cfg.run.threads if args.threads is None else args.threads
    try:
        keys: dict[str, str] = {}
        ensure(cfg, args.stage, force=args.force, device=device, threads=threads, _keys=keys)
        for after in STAGES[args.stage].after:
            ensure(cfg, after, device=device, threads=threads, _keys=keys)
    except StageNotImplemented as e:
        print(f"viewfuse: {e}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print("viewfuse: interrupted; partial outputs were discarded", file=sys.stderr)
        return 130
    except (FileNotFoundError, ValueError, RuntimeError) as e:
        # Readers and stages raise these with the file/key and the problem in the message.
        logging.getLogger("viewfuse").debug("traceback", exc_info=True)
        print(f"viewfuse {args.stage}: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
