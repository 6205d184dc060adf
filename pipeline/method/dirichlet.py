"""View-independent Dirichlet class models of the classifier's probability vector
(Tchuiev & Indelman 2018; docs/design.md §5, "Dirichlet").

Per class c, the classifier's whole softmax vector γ (D entries, summing to 1) is modelled as
``Dir(γ; θ_c)``, whatever the viewpoint. ``fit_dirichlet`` finds the maximum-likelihood θ by
Minka's fixed-point iteration ``θ_j ← ψ⁻¹(ψ(Σθ) + mean_n ln γ_nj)`` from the moment estimate;
``DirichletModels`` holds one θ per class, evaluates ``ln Dir(γ; θ_c)`` and is saved in a folder
(``models/dirichlet/``) as plain arrays (``theta.npz``) with a JSON index (``index.json``: classes,
settings, fit diagnostics, the npz's sha256 and a fingerprint of the parameters). Loading never
unpickles.

Many classes (docs/design.md §5, "Dirichlet"): on a 1000-way ImageNet vector the density is a sum
of 1000 log terms, most of them entries no candidate uses, and the likelihood ratios of two views
reach thousands of nats. With ``models.dirichlet.entries = n`` the models stage also fits, per
candidate set, each candidate's Dirichlet on its vectors reduced to the set's first n chosen
components plus the rest mass (``reduce``); ``DirichletModels.sets`` holds these reduced models
(``select`` = the kept entries, ``input_dim`` = the whole vector's length) and the evaluate stage
uses a target's set where there is one.

Zeros: a float32 softmax underflows to exactly 0 for confident outputs, and ``ln 0`` would make a
class impossible on one entry. Every vector is floored (each entry raised to at least ``floor``)
and renormalised before the log, in the fit and in the likelihood alike.
"""
from __future__ import annotations

import logging
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.special import digamma, gammaln, polygamma

from pipeline.infra.cache import NpzFileError, atomic_path, load_npz, sha256_file
from pipeline.method.bank_index import content_digest, inside, read_index, write_index
from pipeline.infra.outputs import name as out_name

log = logging.getLogger("viewfuse.dirichlet")

FORMAT = "viewfuse.dirichlet_class_models"
VERSION = 1
PARAMS_FILE = "theta.npz"      # inside the folder models/dirichlet/ (pipeline.infra.outputs)
INDEX_FILE = out_name("models", "index")   # the same index name as a GP model bank
EULER = 0.5772156649015329


class DirichletConvergenceWarning(UserWarning):
    """Minka's fixed point stopped at its iteration cap before reaching the tolerance."""


class DirichletFileError(ValueError):
    """The Dirichlet parameter files are missing or malformed; the message names the file."""

    def __init__(self, path: str | Path, problem: str):
        self.path, self.problem = str(path), problem
        super().__init__(f"{path}: {problem}")


# -- numerics ------------------------------------------------------------------------------------
def inv_digamma(y: np.ndarray, iterations: int = 50) -> np.ndarray:
    """x with ψ(x) = y, elementwise: Minka's starting point, then Newton steps (ψ is increasing
    and concave on x > 0, so Newton from this start converges in a handful of steps)."""
    y = np.asarray(y, dtype=float)
    x = np.where(y >= -2.22, np.exp(np.minimum(y, 700.0)) + 0.5, -1.0 / (y + EULER))
    for _ in range(iterations):
        step = (digamma(x) - y) / polygamma(1, x)
        x_new = x - step
        # A Newton step from the right can overshoot below 0 for very negative y: halve instead.
        x_new = np.where(x_new > 0, x_new, 0.5 * x)
        done = np.all(np.abs(x_new - x) <= 1e-15 * np.abs(x))
        x = x_new
        if done:
            break
    return x


def prepare(gamma: np.ndarray, floor: float) -> np.ndarray:
    """Probability vectors (..., D) floored at ``floor`` and renormalised (see the module note)."""
    g = np.asarray(gamma, dtype=float)
    if not np.all(np.isfinite(g)) or np.any(g < 0):
        raise ValueError("Dirichlet: probability vectors must be finite and non-negative")
    g = np.maximum(g, floor)
    return g / g.sum(axis=-1, keepdims=True)


def reduce_vectors(gamma: np.ndarray, select) -> np.ndarray:
    """Probability vectors (..., D) reduced to the entries ``select`` plus the rest mass (..., n + 1)."""
    g = np.asarray(gamma, float)
    kept = g[..., np.asarray(select, dtype=np.int64)]
    return np.concatenate([kept, np.clip(1.0 - kept.sum(axis=-1, keepdims=True), 0.0, None)], axis=-1)


def log_likelihood(theta: np.ndarray, mean_log: np.ndarray, n: int = 1) -> float:
    """n x mean log density of Dir(θ) for data whose mean of ln γ is ``mean_log`` (the sufficient statistic)."""
    theta = np.asarray(theta, float)
    return float(n * (gammaln(theta.sum()) - gammaln(theta).sum() + ((theta - 1.0) * mean_log).sum()))


def moment_estimate(g: np.ndarray) -> np.ndarray:
    """θ from the first two moments: mean m_j and precision s from Σ_j var_j = Σ_j m_j(1-m_j)/(s+1),
    which pools every entry (Minka's formula uses one entry; this one cannot divide by ~0)."""
    m = g.mean(axis=0)
    var = g.var(axis=0).sum()
    s = (m * (1.0 - m)).sum() / var - 1.0 if var > 0 else 1e3
    return m * max(s, 1e-3)


def _fixed_point(theta: np.ndarray, mean_log: np.ndarray) -> np.ndarray:
    """One step of Minka's map: θ_j ← ψ⁻¹(ψ(Σθ) + mean_n ln γ_nj)."""
    return inv_digamma(digamma(theta.sum()) + mean_log)


def fit_dirichlet(gamma: np.ndarray, *, floor: float = 1e-6, tol: float = 1e-10, max_iter: int = 20000,
                  accelerate: bool = True, name: str = "") -> tuple[np.ndarray, dict[str, Any]]:
    """Maximum-likelihood θ (D,) of Dir(γ; θ) for vectors ``gamma`` (N, D), and diagnostics.

    Minka's fixed point from the moment estimate; stops when one step of the map moves no θ_j by
    more than ``tol`` relatively; a ``DirichletConvergenceWarning`` when ``max_iter`` steps of the
    map end first. The map converges linearly, and slowly when the vectors are nearly alike (a
    large precision Σθ: tens of thousands of steps for an untrained network's outputs), so by
    default it is accelerated by SQUAREM extrapolation (two steps, a step-length extrapolation along
    them, then one more step; the plain two steps are kept whenever the extrapolated point leaves
    θ > 0 or lowers the likelihood): the same fixed point, reached in far fewer steps.
    """
    g = prepare(gamma, floor)
    if g.ndim != 2 or len(g) < 2 or g.shape[1] < 2:
        raise ValueError(f"fit_dirichlet{f' ({name})' if name else ''}: need (N >= 2, D >= 2) vectors, got {g.shape}")
    mean_log = np.log(g).mean(axis=0)
    theta = moment_estimate(g)
    init = theta.copy()
    converged, steps, change = False, 0, np.inf
    while steps < max_iter:
        t1 = _fixed_point(theta, mean_log)
        steps += 1
        change = float(np.max(np.abs(t1 - theta) / t1))
        if change < tol:
            theta, converged = t1, True
            break
        if not accelerate or steps + 2 > max_iter:
            theta = t1
            continue
        t2 = _fixed_point(t1, mean_log)
        r, v = t1 - theta, (t2 - t1) - (t1 - theta)
        alpha = -np.sqrt((r @ r) / (v @ v)) if v @ v > 0 else -1.0
        alpha = min(alpha, -1.0)  # alpha = -1 is exactly the two plain steps
        jump = theta - 2.0 * alpha * r + alpha * alpha * v
        if np.all(jump > 0) and log_likelihood(jump, mean_log) >= log_likelihood(t2, mean_log):
            theta_next = _fixed_point(jump, mean_log)
            steps += 2
            change = float(np.max(np.abs(theta_next - jump) / theta_next))
        else:
            theta_next = t2
            steps += 1
            change = float(np.max(np.abs(t2 - t1) / t2))
        theta = theta_next
        if change < tol:
            converged = True
            break
    if not converged:
        warnings.warn(f"Dirichlet fit{f' of {name}' if name else ''}: no convergence after {steps} fixed-point "
                      f"steps (last relative change {change:.3g} > tolerance {tol:g})",
                      DirichletConvergenceWarning, stacklevel=2)
    diag = {"n": int(len(g)), "iterations": int(steps), "converged": converged, "last_relative_change": change,
            "log_likelihood": log_likelihood(theta, mean_log, len(g)), "precision": float(theta.sum()),
            "init_precision": float(init.sum()), "accelerated": bool(accelerate)}
    return theta, diag


# -- the class models ----------------------------------------------------------------------------
class DirichletModels:
    """C classes of Dir(γ; θ_c) over D probability entries; ``theta`` is (C, D)."""

    def __init__(self, classes: Sequence[str], theta, *, floor: float, meta: dict | None = None,
                 select: Sequence[int] | None = None, input_dim: int | None = None,
                 sets: dict[str, "DirichletModels"] | None = None, n_ss: int = 100):
        # select: the input entries kept (the last theta column is then the rest mass), input_dim
        # the length of the vectors log_likelihood takes; None = the whole vector (theta's D).
        self.select = None if select is None else np.asarray(select, dtype=np.int64)
        self.input_dim = int(input_dim) if input_dim is not None else np.shape(theta)[-1]
        self.sets = dict(sets or {})   # candidate-set key (its target) -> reduced models of its classes
        self.n_ss = int(n_ss)          # posterior-cloud size in fusion (evaluate.dirichlet.n_ss; not a parameter)
        self.classes = [str(c) for c in classes]
        self.theta = np.ascontiguousarray(theta, dtype=float)
        self.floor = float(floor)
        self.meta = dict(meta or {})
        C = len(self.classes)
        if C < 1 or len(set(self.classes)) != C:
            raise ValueError(f"DirichletModels: need distinct class names, got {self.classes}")
        if self.theta.ndim != 2 or self.theta.shape[0] != C or self.theta.shape[1] < 2:
            raise ValueError(f"DirichletModels: theta must be ({C}, D >= 2), got {self.theta.shape}")
        if not np.all(np.isfinite(self.theta)) or np.any(self.theta <= 0):
            raise ValueError("DirichletModels: theta must be positive and finite")
        if not 0 < self.floor < 1.0 / self.theta.shape[1]:
            raise ValueError(f"DirichletModels: floor must be in (0, 1/D), got {self.floor}")

    @property
    def dim(self) -> int:
        """Entries of the probability vectors the models take."""
        return int(self.input_dim)

    def reduce(self, gamma: np.ndarray) -> np.ndarray:
        """Input vectors (..., dim) as the models' entries (``reduce_vectors`` with ``select``)."""
        return np.asarray(gamma, float) if self.select is None else reduce_vectors(gamma, self.select)

    def subset(self, classes: Sequence[str]) -> "DirichletModels":
        """The models of ``classes``, in that order (a candidate set)."""
        missing = [c for c in classes if c not in self.classes]
        if missing:
            raise KeyError(f"DirichletModels: no model for class(es) {missing} (modelled: {', '.join(self.classes)})")
        idx = [self.classes.index(c) for c in classes]
        return DirichletModels(classes, self.theta[idx], floor=self.floor, meta=self.meta, select=self.select,
                               input_dim=self.input_dim, n_ss=self.n_ss)

    def log_likelihood(self, gamma: np.ndarray) -> np.ndarray:
        """ln Dir(γ; θ_c) for vectors (..., D): (..., C)."""
        g = np.asarray(gamma, float)
        if g.shape[-1] != self.dim:
            raise ValueError(f"DirichletModels: vectors have {g.shape[-1]} entries, the models {self.dim}")
        lg = np.log(prepare(self.reduce(g), self.floor))
        norm = gammaln(self.theta.sum(axis=1)) - gammaln(self.theta).sum(axis=1)        # (C,)
        return lg @ (self.theta - 1.0).T + norm

    def for_set(self, key: str, classes: Sequence[str]) -> "DirichletModels":
        """The reduced models of candidate set ``key`` in the order ``classes``, else ``subset(classes)``."""
        if key not in self.sets:
            return self.subset(classes)
        out = self.sets[key].subset(classes)
        out.n_ss = self.n_ss
        return out

    def fingerprint(self) -> str:
        """The one content digest (``bank_index.content_digest``) of the parameters, classes and
        floor (and every reduced set): changes whenever the models do."""
        parts = [{"classes": self.classes, "floor": self.floor}, np.asarray(self.theta, "<f8")]
        for key in sorted(self.sets):
            m = self.sets[key]
            parts += [{"set": key, "classes": m.classes, "select": m.select.tolist()}, np.asarray(m.theta, "<f8")]
        return content_digest(*parts)

    def save(self, folder: str | Path, extra: dict | None = None) -> Path:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        with atomic_path(folder / PARAMS_FILE) as tmp:
            with open(tmp, "wb") as fh:  # a file object: np.savez must not append ".npz"
                keys = sorted(self.sets)
                arrays = {f"set{i}_{part}": getattr(self.sets[k], part) for i, k in enumerate(keys)
                          for part in ("theta", "select")}
                np.savez(fh, theta=self.theta, floor=np.float64(self.floor), **arrays)
            digest = sha256_file(tmp)
        index = {"format": FORMAT, "version": VERSION, "density": "Dir(gamma; theta_c), gamma floored then renormalised",
                 "classes": self.classes, "dim": self.dim, "floor": self.floor, "file": PARAMS_FILE,
                 "sha256": digest, "fingerprint": self.fingerprint(), "meta": self.meta,
                 "theta": {c: self.theta[i].tolist() for i, c in enumerate(self.classes)},
                 "sets": {k: {"array": f"set{i}", "classes": self.sets[k].classes,
                              "entries": self.sets[k].select.tolist()} for i, k in enumerate(sorted(self.sets))}}
        return write_index(folder / INDEX_FILE, index, extra)

    @classmethod
    def load(cls, folder: str | Path) -> "DirichletModels":
        folder = Path(folder)
        ipath = folder / INDEX_FILE
        index = read_index(ipath, FORMAT, VERSION, ("classes", "sha256", "fingerprint"), DirichletFileError,
                           "Dirichlet model index")
        if not (folder / PARAMS_FILE).is_file():
            raise DirichletFileError(folder / PARAMS_FILE, "Dirichlet parameter file not found (rerun the 'models' stage)")
        path = inside(folder, PARAMS_FILE, ipath, DirichletFileError, "the parameter file")  # a link out is refused
        if sha256_file(path) != index["sha256"]:
            raise DirichletFileError(path, f"content differs from the sha256 recorded in {ipath}; rerun the 'models' stage")
        try:
            data = load_npz(path)
        except NpzFileError as e:
            raise DirichletFileError(path, f"unreadable parameter file: {e.problem}") from None
        if "theta" not in data or "floor" not in data:
            raise DirichletFileError(path, "missing array 'theta' or 'floor'")
        try:
            sets = {k: cls(v["classes"], data[f"{v['array']}_theta"], floor=float(data["floor"]),
                           select=data[f"{v['array']}_select"], input_dim=data["theta"].shape[1])
                    for k, v in (index.get("sets") or {}).items()}
            out = cls(index["classes"], data["theta"], floor=float(data["floor"]), meta=index.get("meta"), sets=sets)
        except (ValueError, KeyError) as e:
            raise DirichletFileError(path, str(e)) from None
        if out.fingerprint() != index["fingerprint"]:
            raise DirichletFileError(ipath, "fingerprint does not match the parameters; rerun the 'models' stage")
        return out


def fit_class_dirichlets(vectors: dict[str, np.ndarray], *, floor: float, tol: float, max_iter: int,
                         accelerate: bool = True) -> tuple[DirichletModels, list[dict[str, Any]]]:
    """One Dirichlet per class from its probability vectors (N_c, D): the models and per-class
    diagnostics (warnings recorded, and logged, rather than lost)."""
    classes = list(vectors)
    thetas, diags = [], []
    for cls in classes:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DirichletConvergenceWarning)
            theta, d = fit_dirichlet(vectors[cls], floor=floor, tol=tol, max_iter=max_iter, accelerate=accelerate,
                                     name=cls)
        msgs = [str(w.message) for w in caught if issubclass(w.category, DirichletConvergenceWarning)]
        for m in msgs:
            log.warning("%s", m)
        thetas.append(theta)
        diags.append({"class": cls, **d, "warnings": msgs})
    return DirichletModels(classes, np.stack(thetas), floor=floor), diags


def class_vectors(views, dcfg) -> dict[str, np.ndarray]:
    """Each modelled class's probability vectors (N_c, D) of its training ring
    (``pipeline.method.provider.TrainingViews``): the passes ``dcfg.passes`` names."""
    passes = views.passes() if dcfg.passes != "deterministic" else {}
    vectors = {}
    for cls in views.classes:
        parts = []
        if dcfg.passes in ("deterministic", "both"):
            parts.append(views.scores[views.objects == cls])
        if dcfg.passes in ("dropout", "both"):
            if not passes.get(cls):
                raise views.error(f"models.dirichlet.passes = {dcfg.passes!r} needs MC-dropout passes of the "
                                  f"BigBIRD views (features.bigbird_samples > 0); class {cls!r} has none")
            parts.extend(passes[cls][a] for a in sorted(passes[cls]))
        g = np.concatenate(parts) if parts else np.empty((0, views.scores.shape[1]))
        if len(g) < 2:
            raise views.error(f"class {cls!r}: {len(g)} probability vector(s) for its Dirichlet fit")
        dev = float(np.max(np.abs(g.sum(axis=1) - 1.0)))
        if dev > 1e-3:
            raise views.error(f"class {cls!r}: score vectors sum to 1 only within {dev:.3g}: the Dirichlet "
                              "method needs probability vectors (softmax outputs)")
        vectors[cls] = g
    return vectors


def reduced_sets(vectors: dict[str, np.ndarray], plan: dict, dcfg, dim: int
                 ) -> tuple[dict[str, DirichletModels], list[dict[str, Any]]]:
    """Per candidate set: its classes' Dirichlets on (first ``dcfg.entries`` chosen components, rest mass)."""
    sets, diags = {}, []
    for target in sorted(plan):
        p = plan[target]
        select = [int(i) for i in p["components"][:dcfg.entries]]
        red, d = fit_class_dirichlets({c: reduce_vectors(vectors[c], select) for c in p["classes"]}, floor=dcfg.floor,
                                      tol=dcfg.tol, max_iter=dcfg.max_iter, accelerate=dcfg.accelerate)
        sets[target] = DirichletModels(red.classes, red.theta, floor=dcfg.floor, select=select, input_dim=dim)
        diags.extend({**x, "candidate_set": target, "entries": select} for x in d)
    return sets, diags
