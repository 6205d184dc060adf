"""One contract for every kind of extension (docs/extending.md): ``register`` (one spelling for a
fusion method, a model provider, a classifier, a planner, a metric and a dataset source) and the
registered entries of each kind, ``methods()``, ``classifiers()``, ``planners()``, ``metrics()``
and ``datasets()``, each an ``Entry``: the key as a string (so lists of keys read as before) that
also carries the kind, the label, the colour and the note the report shows, and the registered
object. Every breach at the boundary is an ``ExtensionError`` naming kind, key, hook and cause."""
from __future__ import annotations

from pipeline.evaluation.metrics import spec as metric_spec
from pipeline.infra import datasets as dataset_registry
from pipeline.infra.extension import ExtensionError
from pipeline.method import method_base, provider
from pipeline.method import registry as method_registry
from pipeline.planning import planners as planner_registry
from pipeline.scoring import classifiers as classifier_registry


class Entry(str):
    """A registered entry: its key (this string) with ``kind``, ``label``, ``color``, ``note`` and
    ``obj`` (the registered method instance, classifier, planner class, Metric or source)."""
    kind: str
    label: str
    color: str
    note: str
    obj: object

    def __new__(cls, kind: str, key: str, label: str, color: str, note: str, obj) -> "Entry":
        e = super().__new__(cls, key)
        e.kind, e.label, e.color, e.note, e.obj = kind, label or key, color, note, obj
        return e

    @property
    def key(self) -> str:
        return str(self)


def register(obj):
    """Register ``obj`` in its kind's registry; usable as a class decorator. A ``FusionMethod`` or
    ``ModelProvider`` subclass, a ``Classifier`` (class or instance), a ``Planner`` subclass, a
    ``Metric`` (with its ``key``) or a ``DatasetSource`` (class or instance). The contract is
    checked first: every breach is one ``ExtensionError`` naming the kind and key."""
    if isinstance(obj, metric_spec.Metric):
        return metric_spec.register_metric(obj)
    kinds = ((method_base.FusionMethod, method_registry.register), (provider.ModelProvider, provider.register_provider),
             (classifier_registry.Classifier, classifier_registry.register_classifier),
             (planner_registry.Planner, planner_registry.register_planner),
             (dataset_registry.DatasetSource, dataset_registry.register_dataset))
    for base, add in kinds:
        if (isinstance(obj, type) and issubclass(obj, base)) or (isinstance(obj, base) and base not in
                                                                   (method_base.FusionMethod, planner_registry.Planner,
                                                                    provider.ModelProvider)):
            return add(obj)
    raise ExtensionError.of("extension", getattr(obj, "key", repr(obj)[:60]), "register",
                            "register: obj must be a FusionMethod, ModelProvider or Planner subclass, a Classifier, a "
                            f"Metric or a DatasetSource, got {obj!r:.60}")


def methods(*, attribution: bool = False) -> list[Entry]:
    """The registered fusion methods, in order (built-ins first, then yours); ``attribution``
    adds the ingredient variants."""
    if not isinstance(attribution, bool):
        raise TypeError(f"methods: attribution must be True or False, got {type(attribution).__name__}")
    return [Entry("fusion method", m.key, m.label, m.color, m.note, m)
            for m in method_registry.methods(attribution=attribution)]


def classifiers() -> list[Entry]:
    """The registered classifiers (``classifier.arch`` values), then the families as
    ``<prefix>:<model>``."""
    reg = classifier_registry.REGISTRY
    out = []
    for n in classifier_registry.names():
        c = reg[n] if n in reg else None
        out.append(Entry("classifier", n, c.label if c else f"any model of the {n.partition(':')[0]} family",
                         c.color if c else "#555555", c.note if c else "", c))
    return out


def planners() -> list[Entry]:
    """The registered planners, the built-ins first."""
    return [Entry("planner", k, p.label, p.color, p.note, p) for k, p in planner_registry.PLANNERS.items()]


def metrics() -> list[Entry]:
    """The registered metrics (what every cell and population summary reports), the built-ins first."""
    return [Entry("metric", k, m.label, m.color, m.note, m) for k, m in metric_spec.METRICS.items()]


def datasets() -> list[Entry]:
    """The registered dataset sources (``data.source`` values), the built-ins first."""
    return [Entry("dataset source", k, s.label or s.doc or k, s.color, s.note, s)
            for k, s in dataset_registry.SOURCES.items()]
