"""``check_extension(obj)``, as scikit-learn's ``check_estimator``: the contract of ``obj``'s kind
checked at once, before any stage runs. First the declarations registration checks (key, label,
colour, note, required hooks and their signatures: each kind's ``problems``), then one tiny case
of the kind, run through the same calls the stages make:

- a fusion method fuses a 3-view track of 3 candidates (2 realizations) from GP models fitted
  here, through ``output_check.call_checked`` (read-only inputs, output checked; its
  ``single_view`` and ``fuse_tracks`` too, when it has them);
- a classifier builds a 3-class network, names its last Linear weight (3 rows) and scores two
  images with MC dropout at its declared site;
- a planner plans one 4-step episode on an 8-view ring (``episode.run_episode``);
- a metric reduces random per-step values vectorized over a leading axis (one finite number each);
- a dataset source that reads photographs (a ``TurntableSource``) is read with ``cfg`` (default:
  the default config) and its output checked (``read_check.check_photos``); a read that cannot
  run without your data is said in the returned notes, not a breach.

Every breach is collected; one ``ExtensionError`` lists them all (kind, key, each hook and cause).
Returns the notes (what ran) when there is none. Nothing is registered.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.evaluation.metrics import spec as metric_spec
from pipeline.infra import datasets as dataset_registry
from pipeline.infra.extension import ExtensionError, declared_key
from pipeline.method import method_base
from pipeline.planning import planners as planner_registry
from pipeline.scoring.classifiers import registry as classifier_registry
from pipeline.method.geometry import relative_inputs, sample_localization
from pipeline.method.output_check import call_checked
from pipeline.method.gp import GPClassModels
from pipeline.planning.graph import MoveGraph
from pipeline.planning.world import World
from pipeline.planning.belief import Belief
from pipeline.planning.eig import standard_draws
from pipeline.planning.episode import run_episode
from loaders.real_imagery.read_check import check_photos
from pipeline.infra.config import Config

K, C, N_S, R, N_X = 3, 3, 2, 2, 4
# A hook still running after this long (wall clock: the first call may compile kernels) is a breach.
LIMIT = 600.0
CLASSES = ("mug", "bowl", "can")


def _kind(obj) -> tuple[str, object]:
    if isinstance(obj, metric_spec.Metric):
        return "metric", obj
    for kind, base in (("fusion method", method_base.FusionMethod), ("planner", planner_registry.Planner),
                       ("classifier", classifier_registry.Classifier), ("dataset source", dataset_registry.DatasetSource)):
        if (isinstance(obj, type) and issubclass(obj, base)) or isinstance(obj, base):
            return kind, base
    raise ExtensionError.of("extension", getattr(obj, "key", repr(obj)[:60]), "check_extension",
                            f"not a FusionMethod, Planner, Classifier, Metric or DatasetSource (got {obj!r:.60})")


def _models():
    from viewfuse.api import fit_models

    rng = np.random.default_rng(0)
    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    samples = {n: (ang, np.stack([0.5 + 0.3 * np.cos(ang - c), 0.5 - 0.2 * np.cos(ang - c)], 1)
                   + rng.normal(0, 0.02, (8, 2))) for c, n in enumerate(CLASSES)}
    return fit_models(samples, restarts=0)


def _simplex(rng, shape) -> np.ndarray:
    """Random probability vectors (the last axis sums to one)."""
    p = rng.random(shape) + 0.05
    return p / p.sum(axis=-1, keepdims=True)


def _method(cls, notes: list[str]) -> list[str]:

    m = cls() if isinstance(cls, type) else cls
    known = {"gp", "scores", "probs"}
    if not set(m.needs) <= known:
        notes.append(f"fuse not run: it needs the models of {sorted(set(m.needs) - known)} (run it through the chain)")
        return []
    rng = np.random.default_rng(1)
    models = _models()
    cams = 2.0 * np.stack([np.cos(np.linspace(0, 1, K)), np.sin(np.linspace(0, 1, K))], 1)
    est = cams[None] + rng.normal(0, 0.05, (R, K, 2))
    inputs = lambda p: relative_inputs(p, np.zeros(2), 0.0, unit_circle=True)  # noqa: E731
    t = method_base.TrackInput(dropout=rng.normal(0.5, 0.1, (K, N_S, 2)), gp=models,
                               own=_simplex(rng, (K, N_S, C)), probs=_simplex(rng, (K, N_S, 5)),
                               estimates=est, samples=sample_localization(est, 0.1, N_X, rng), inputs=inputs,
                               rng=np.random.default_rng(2))
    out = []
    for hook, args in (("fuse", (t,)), ("single_view", (dataclasses.replace(t, estimates=cams[None]),))):
        if hook == "single_view" and type(m).single_view is method_base.FusionMethod.single_view:
            continue
        try:
            call_checked(m, hook, *args, seconds=LIMIT, setting="check_extension's limit")
            notes.append(f"{hook} ran on {K} views of {C} candidates")
        except ExtensionError as e:
            out.append(str(e))
    if m.planning:
        tt = dataclasses.replace(t, dropout=np.broadcast_to(t.dropout, (R,) + t.dropout.shape).copy())
        try:
            call_checked(m, "fuse_tracks", tt, shape=(R, K, None), seconds=LIMIT, setting="check_extension's limit")
            notes.append(f"fuse_tracks ran on {R} tracks")
        except ExtensionError as e:
            out.append(str(e))
    return out


def _classifier(entry, notes: list[str]) -> list[str]:
    import torch

    from pipeline.scoring.mc_dropout import MCDropoutScorer, crop_seed

    inst = entry() if isinstance(entry, type) else entry
    key = declared_key(inst)
    bad = lambda hook, cause: ExtensionError.of("classifier", key, hook, cause).args[0]  # noqa: E731
    try:
        net = inst.build(C, 0.5, 0.0)
    except Exception as e:  # noqa: BLE001 - reported as a breach naming the hook
        return [bad("build", f"{type(e).__name__}: {e}")]
    state = net.state_dict() if hasattr(net, "state_dict") else {}
    w = state.get(inst.last_linear_key())
    if w is None or w.shape[0] != C:
        return [bad("last_linear_key", f"{inst.last_linear_key()!r} is not a weight with {C} rows in build({C}, ...)'s "
                                       f"state dict (its keys end with {list(state)[-3:]})")]
    try:
        torch.manual_seed(0)
        det, mc = MCDropoutScorer(net, onednn=False).score(torch.rand(2, 3, 64, 64), [crop_seed(0, "a"),
                                                                                      crop_seed(0, "b")], 3)
    except Exception as e:  # noqa: BLE001
        return [bad("build", f"the network does not score with MC dropout: {type(e).__name__}: {e}")]
    notes.append(f"build({C}) scored two images with MC dropout: {tuple(det.shape)}, {tuple(mc.shape)}")
    return []


def _ring():

    th = np.linspace(-np.pi, np.pi, 36, endpoint=False)
    X = np.stack([np.cos(th), np.sin(th)], -1)
    a = 0.5 + 0.4 * np.exp(-np.angle(np.exp(1j * (th - np.pi))) ** 2 / 0.125)
    models = GPClassModels(["a", "b"], [0], [X, X], [a[None], np.full_like(th, 0.5)[None]], mean=[[0.5], [0.5]],
                           amplitude=[[0.05], [0.01]], length_scale=[[0.3], [1.0]], noise=[[1e-3], [1e-3]])
    names = [f"v{i}" for i in range(8)]
    moves = {n: {"left": names[(i + 1) % 8], "right": names[(i - 1) % 8]} for i, n in enumerate(names)}
    xy = {n: 1.5 * np.array([np.cos(i * np.pi / 4), np.sin(i * np.pi / 4)]) for i, n in enumerate(names)}
    drop = {n: np.full((5, 1), 0.9 if n == "v4" else 0.5) for n in names}
    world = World("obj", "scan", ("a", "b"), (0,), 0, MoveGraph.from_moves(moves), xy, drop, np.zeros(2), 0.0,
                  tuple(names[:4]))
    return models, world


def _planner(cls, notes: list[str]) -> list[str]:

    key = declared_key(cls)
    models, world = _ring()
    try:
        planner = cls.make(standard_draws(8, 1, 0), None)
    except Exception as e:  # noqa: BLE001
        return [ExtensionError.of("planner", key, "make", f"{type(e).__name__}: {e}").args[0]]
    planner.key = key
    belief = Belief(models, world, bias=(0.0, 0.0), est_sigma=0.0, sigma=0.1, n_x=8, key=(0,))
    try:
        ep = run_episode(belief, planner, "v0", budget=4, confidence=None, horizon=2, rng=np.random.default_rng(0))
    except ExtensionError as e:
        return [str(e)]
    notes.append(f"an episode on an 8-view ring chose {ep.nodes[1:]}")
    return []


def _metric(metric, notes: list[str]) -> list[str]:
    rng = np.random.default_rng(0)
    cols = (metric.column,) if isinstance(metric.column, str) else tuple(metric.column)
    values = {"correct": rng.random((5, R * K)) < 0.5, "p_truth": rng.random((5, R * K))}
    xs = [values.get(c, rng.random((5, R * K))).astype(float) for c in cols]
    where = lambda cause: ExtensionError.of("metric", metric.key, "reduce", cause).args[0]  # noqa: E731
    try:
        out = np.asarray(metric.reduce(*xs, params=metric_spec.Params(0.99, 15)))
    except Exception as e:  # noqa: BLE001
        return [where(f"{type(e).__name__}: {e}")]
    if out.shape != (5,) or out.dtype.kind not in "fiub" or not np.isfinite(out.astype(float)).all():
        return [where(f"values (5, {R * K}) gave {out.dtype} {out.shape}; expected one finite number per leading "
                      "index (5,): reduce the last axis only")]
    notes.append(f"reduce gave {out.shape} from values (5, {R * K})")
    return []


def _dataset(entry, notes: list[str], cfg) -> list[str]:

    inst = entry() if isinstance(entry, type) else entry
    if not any(h == "read" for h, _, _ in inst.required_hooks):
        notes.append("write(ctx) not run: it writes a data folder (run the data stage)")
        return []
    if cfg is None:

        cfg = Config()
    skipped: list = []
    skips = type("Skips", (), {"handle": lambda self, err, *a: skipped.append(err)})()
    try:
        photos = inst.read(cfg, skips)
    except Exception as e:  # noqa: BLE001 - it needs the user's data: said, not a breach
        notes.append(f"read(cfg, skips) not run to the end on this config ({type(e).__name__}: {e}); pass cfg=")
        return []
    try:
        check_photos(declared_key(inst), photos)
    except ExtensionError as e:
        return [str(e)]
    notes.append(f"read gave {len(photos)} objects ({len(skipped)} skipped)")
    return []


def check_extension(obj, *, cfg=None) -> list[str]:
    """Every breach of ``obj``'s contract at once, as one ``ExtensionError``; else the notes of
    what ran (module docstring). ``cfg``: the config a dataset source's ``read`` gets."""
    kind, _ = _kind(obj)
    problems = {"fusion method": method_base.problems, "planner": planner_registry.problems,
                "classifier": classifier_registry.problems, "metric": metric_spec.problems,
                "dataset source": lambda o: dataset_registry.problems(o, complete=True)}[kind]
    target = obj if kind != "fusion method" or isinstance(obj, type) else type(obj)
    key = obj.key if kind == "metric" else declared_key(obj)
    breaches = [f"{kind} {key!r} (register): {p}" for p in problems(target)]
    notes: list[str] = []
    if not breaches:
        run = {"fusion method": lambda: _method(obj, notes), "planner": lambda: _planner(obj, notes),
               "classifier": lambda: _classifier(obj, notes), "metric": lambda: _metric(obj, notes),
               "dataset source": lambda: _dataset(obj, notes, cfg)}[kind]
        breaches += run()
    if breaches:
        raise ExtensionError(f"check_extension: {len(breaches)} breach(es) of the {kind} contract:\n  "
                             + "\n  ".join(breaches), kind=kind, key=str(key), hook="check_extension",
                             cause="; ".join(breaches))
    return notes
