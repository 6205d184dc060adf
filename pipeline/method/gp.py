"""Per-class, viewpoint-dependent GP models of classifier scores (docs/design.md §5, paper Eq. 13-17).

One GP per (class c, component f): constant prior mean m (the training mean), kernel
``k(x, x') = a·exp(-‖x - x'‖² / (2ℓ²))`` and white noise σ_n² on training *and* test
measurements. Inputs are 2D: unit-circle viewing directions (real data) or plain relative positions
(simulation scenarios); nothing here assumes the circle.

``GPClassModels.predict`` is the joint predictive the fusion engine is built on; it equals
scikit-learn's ``GaussianProcessRegressor(C*RBF + White).predict(X, return_cov=True)`` (fitted on
Y - m, plus m). Train-test kernels are formed as large matrix products and the training solve is
one triangular solve with the training Cholesky factor over all test rows, so a whole batch of
trajectories costs a few BLAS calls per (class, component).

Test-domain variance: ``with_test_variance(extra)`` gives the same models whose *test*
measurements carry noise σ_n² + δ² per (class, component) (``test_noise``) while the training
factors keep σ_n²; ``predict`` and ``marginal`` use ``test_noise``, so every fusion engine built on
them (and any engine that reads ``test_noise`` for the test diagonal) sees the calibrated
likelihood unchanged (docs/design.md §5, "Calibrated likelihood").

Files: ``index.json`` plus one ``<class>.npz`` per class (arrays only; loading never unpickles;
``pipeline/method/gp_files.py``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from pipeline.infra.outputs import name as out_name
from pipeline.method.bank_index import content_digest

INDEX = out_name("models", "index")  # a model bank folder's index (models/, its ablations, simulate/models)

FORMAT = "viewfuse.gp_class_models"
VERSION = 1
KERNEL_TEXT = "a*exp(-|x-x'|^2/(2*l^2)) + noise*delta(x,x'), constant mean m"


class ModelFileError(ValueError):
    """A model folder or file is missing or malformed; the message names the file."""

    def __init__(self, path: str | Path, problem: str):
        self.path, self.problem = str(path), problem
        super().__init__(f"{path}: {problem}")


@dataclass
class _ClassFactors:
    center: np.ndarray      # (d,) training-input centre: distances are computed on centred inputs
    T: np.ndarray           # (N, d) centred training inputs
    tsq: np.ndarray         # (N,) squared norms of T
    alpha: np.ndarray       # (F, N) H (y - m)
    L: list[np.ndarray]     # F Fortran-ordered lower Cholesky factors of K_T + σ_n² I



def predictive_covariance(models, c: int, f: int, V3: np.ndarray, D2tt: np.ndarray, kk: np.ndarray,
                          out: np.ndarray, inst: tuple[float, float] | None = None) -> np.ndarray:
    """The joint predictive covariance of (class c, component f) at B trajectories of K views, the
    one place it is assembled (``GPClassModels.joint``, the engine's exact route):
    ``a·exp(-D²/2ℓ²) + (σ_n² + δ²) I [+ an unseen instance's a_i·exp(-D²/2λ²)] - V3 V3ᵀ`` into
    ``out`` (B, K, K). V3 (B, K, N): the test rows whitened by the training factor; D2tt (B, K, K):
    within-trajectory squared distances; kk (B, K, K): scratch; ``inst``: (a_i, λ) or None."""
    S = np.matmul(V3, V3.transpose(0, 2, 1))
    ell = models.length_scale[c, f]
    np.multiply(D2tt, -0.5 / (ell * ell), out=kk)
    np.exp(kk, out=kk)
    kk *= models.amplitude[c, f]
    diag = np.arange(kk.shape[-1])
    kk[:, diag, diag] += models.test_noise[c, f]   # σ_n² + the test-domain δ²
    if inst is not None:   # an unseen instance's deviation, shared by every view
        kk += inst[0] * np.exp(D2tt * (-0.5 / (inst[1] * inst[1])))
    return np.subtract(kk, S, out=out)

class GPClassModels:
    """C classes × F components of GPs; each class has its own training inputs.

    Attributes: ``classes`` (C names), ``components`` (F score indices), ``X`` list of (N_c, d)
    training inputs, ``Y`` list of (F, N_c) targets, ``mean``, ``amplitude``, ``length_scale``,
    ``noise`` (C, F) hyperparameters (raw units), ``component_names`` (F or None), ``meta`` (dict).
    """

    def __init__(self, classes: Sequence[str], components: Sequence[int], X: Sequence[np.ndarray],
                 Y: Sequence[np.ndarray], mean, amplitude, length_scale, noise, *,
                 component_names: Sequence[str] | None = None, meta: dict | None = None):
        self.classes = [str(c) for c in classes]
        self.components = [int(i) for i in components]
        C, F = len(self.classes), len(self.components)
        if C < 1 or F < 1:
            raise ValueError(f"GPClassModels: need at least one class and one component, got {C} and {F}")
        if len(set(self.classes)) != C:
            raise ValueError(f"GPClassModels: duplicate class names in {self.classes}")
        if len(X) != C or len(Y) != C:
            raise ValueError(f"GPClassModels: {C} classes but {len(X)} input sets and {len(Y)} target sets")
        self.X = [np.ascontiguousarray(x, dtype=float) for x in X]
        self.Y = [np.ascontiguousarray(y, dtype=float) for y in Y]
        d = self.X[0].shape[-1] if self.X[0].ndim == 2 else -1
        for c, (x, y) in enumerate(zip(self.X, self.Y)):
            name = self.classes[c]
            if x.ndim != 2 or x.shape[1] != d or len(x) < 1:
                raise ValueError(f"GPClassModels: class {name!r}: inputs must be (N, {d}), got {x.shape}")
            if y.shape != (F, len(x)):
                raise ValueError(f"GPClassModels: class {name!r}: targets must be ({F}, {len(x)}), got {y.shape}")
            if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
                raise ValueError(f"GPClassModels: class {name!r}: non-finite training inputs or targets")
        self.mean = self._param(mean, "mean", C, F, positive=False)
        self.amplitude = self._param(amplitude, "amplitude", C, F)
        self.length_scale = self._param(length_scale, "length_scale", C, F)
        self.noise = self._param(noise, "noise", C, F)
        self.component_names = None if component_names is None else [str(s) for s in component_names]
        if self.component_names is not None and len(self.component_names) != F:
            raise ValueError(f"GPClassModels: {F} components but {len(self.component_names)} component names")
        self.meta = dict(meta or {})
        self._factors: list[_ClassFactors] | None = None
        self.test_variance = np.zeros((C, F))
        # {method key: ν} of the heavy-tailed methods (pipeline/method/student_t.py), fitted per
        # cross-fitting fold at evaluate (``with_tail_df``); empty: those methods do not apply
        self.tail_df: dict[str, float] = {}

    @property
    def test_noise(self) -> np.ndarray:
        """(C, F) noise variance of a test measurement: σ_n² plus the test-domain variance δ²."""
        return self.noise + self.test_variance

    def with_test_variance(self, extra) -> "GPClassModels":
        """These models with δ² = ``extra`` ((C, F), (F,) or a scalar, >= 0) added to the noise of
        test measurements only; training arrays and factors are shared, not recomputed."""
        d = np.broadcast_to(np.asarray(extra, dtype=float), self.noise.shape).copy()
        if not np.all(np.isfinite(d)) or np.any(d < 0):
            raise ValueError(f"with_test_variance: variances must be finite and >= 0, got {d.tolist()}")
        out = self._copy(slice(None), slice(None))
        out._factors = self._factors
        out.test_variance = self.test_variance + d
        return out

    def with_tail_df(self, nus: dict) -> "GPClassModels":
        """These models with the Student-t degrees of freedom {method key: ν > 0} of the ``*_t``
        methods; nothing else changes (arrays and factors shared)."""
        bad = {k: v for k, v in dict(nus).items() if not (isinstance(v, (int, float)) and 0 < v < float("inf"))}
        if bad:
            raise ValueError(f"with_tail_df: degrees of freedom must be finite numbers > 0, got {bad}")
        out = self._copy(slice(None), slice(None))
        out._factors = self._factors
        out.test_variance = self.test_variance.copy()
        out.tail_df = {**self.tail_df, **{str(k): float(v) for k, v in dict(nus).items()}}
        return out

    def _copy(self, ci, fi) -> "GPClassModels":
        idx = range(self.n_classes)[ci] if isinstance(ci, slice) else ci
        fidx = list(range(self.n_components)[fi]) if isinstance(fi, slice) else list(fi)
        names = None if self.component_names is None else [self.component_names[i] for i in fidx]
        out = GPClassModels([self.classes[i] for i in idx], [self.components[i] for i in fidx],
                            [self.X[i] for i in idx],
                            [self.Y[i] if fidx == list(range(self.n_components)) else self.Y[i][fidx] for i in idx],
                            self.mean[np.ix_(list(idx), fidx)], self.amplitude[np.ix_(list(idx), fidx)],
                            self.length_scale[np.ix_(list(idx), fidx)], self.noise[np.ix_(list(idx), fidx)],
                            component_names=names, meta=self.meta)
        out.test_variance = self.test_variance[np.ix_(list(idx), fidx)].copy()
        out.tail_df = dict(self.tail_df)
        return out

    @staticmethod
    def _param(v, name: str, C: int, F: int, positive: bool = True) -> np.ndarray:
        a = np.array(v, dtype=float)
        if a.shape != (C, F):
            raise ValueError(f"GPClassModels: '{name}' must have shape ({C}, {F}), got {a.shape}")
        if not np.all(np.isfinite(a)) or (positive and np.any(a <= 0)):
            raise ValueError(f"GPClassModels: '{name}' must be finite{' and > 0' if positive else ''}: {a.tolist()}")
        return a

    # -- shape helpers ----------------------------------------------------------------------
    @property
    def n_classes(self) -> int:
        return len(self.classes)

    @property
    def n_components(self) -> int:
        return len(self.components)

    @property
    def input_dim(self) -> int:
        return self.X[0].shape[1]

    def __repr__(self) -> str:
        return (f"GPClassModels(classes={self.classes}, components={self.components}, "
                f"n_train={[len(x) for x in self.X]})")

    def select(self, classes: Sequence[str]) -> "GPClassModels":
        """The models of ``classes`` (a subset or reordering); training arrays are shared, not copied."""
        idx = []
        for c in classes:
            if c not in self.classes:
                raise KeyError(f"class {c!r} is not modelled (classes: {', '.join(self.classes)})")
            idx.append(self.classes.index(c))
        return self._copy(idx, slice(None))

    def subset(self, classes: Sequence[str], components: Sequence[int]) -> "GPClassModels":
        """The models of ``classes`` restricted to score ``components`` (both subsets or reorderings):
        one model bank serves every candidate set."""
        sub = self.select(classes)
        try:
            fi = [self.components.index(int(i)) for i in components]
        except ValueError:
            raise KeyError(f"components {list(components)} are not all modelled (have {self.components})") from None
        return sub._copy(slice(None), fi)

    # -- training-side factors (computed once) ----------------------------------------------
    def factors(self) -> list[_ClassFactors]:
        if self._factors is None:
            from scipy.linalg import cho_solve

            out = []
            for c, (x, y) in enumerate(zip(self.X, self.Y)):
                center = x.mean(axis=0)
                T = x - center
                diff = T[:, None, :] - T[None, :, :]
                D2 = np.einsum("ijk,ijk->ij", diff, diff)
                N, F = len(T), self.n_components
                alpha = np.empty((F, N))
                Ls = []
                for f in range(F):
                    Ktt = self._train_cov(c, f, D2)
                    Ktt[np.diag_indices(N)] += self.noise[c, f]
                    try:
                        L = np.linalg.cholesky(Ktt)
                    except np.linalg.LinAlgError:
                        raise ValueError(
                            f"GP of class {self.classes[c]!r}, component {self.components[f]}: training "
                            f"covariance is not positive definite ({self._describe(c, f)}); raise the noise "
                            f"lower bound") from None
                    alpha[f] = cho_solve((L, True), y[f] - self.mean[c, f])
                    Ls.append(np.asfortranarray(L))
                out.append(_ClassFactors(center, T, np.einsum("ij,ij->i", T, T), alpha, Ls))
            self._factors = out
        return self._factors

    def _train_cov(self, c: int, f: int, D2: np.ndarray) -> np.ndarray:
        """GP (c, f)'s noise-free training covariance from the squared distances of class c's
        training inputs (a subclass adds its terms here, so ``factors`` factorises each GP once)."""
        ell = self.length_scale[c, f]
        return self.amplitude[c, f] * np.exp(-D2 / (2.0 * ell * ell))

    def instance_parameters(self, c: int, f: int) -> tuple[float, float] | None:
        """(a_i, λ) of GP (c, f)'s unseen-instance term, or None: plain models have none
        (models with an instance term override it)."""
        return None

    def _describe(self, c: int, f: int) -> str:
        return (f"amplitude {self.amplitude[c, f]:g}, length scale {self.length_scale[c, f]:g}, "
                f"noise {self.noise[c, f]:g}")

    def _sqdist_train(self, c: int, flat: np.ndarray) -> np.ndarray:
        """‖x - x_T‖² for test rows (n, d) against class c's training inputs: one GEMM."""
        fc = self.factors()[c]
        x = flat - fc.center
        D2 = x @ (-2.0 * fc.T.T)
        D2 += np.einsum("ij,ij->i", x, x)[:, None]
        D2 += fc.tsq[None, :]
        np.maximum(D2, 0.0, out=D2)
        return D2

    def _kernel_from_sqdist(self, c: int, f: int, D2: np.ndarray, out: np.ndarray | None = None):
        ell = self.length_scale[c, f]
        out = np.multiply(D2, -0.5 / (ell * ell), out=out)
        out += np.log(self.amplitude[c, f])      # a·exp(t) as exp(t + log a): one pass fewer
        return np.exp(out, out=out)

    def whitened(self, c: int, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predictive mean (n, F) and whitened cross terms V (F, n, N_c) of class c at rows X (n, d).

        ``V[f] @ V[f].T = K(X, X_T) H K(X_T, X)``, so cov = K(X, X) + σ_n² I - V Vᵀ.
        (Rows of V are L⁻¹ k(X_T, x) with L the training Cholesky factor.)
        """
        X = np.ascontiguousarray(X, dtype=float)
        fc = self.factors()[c]
        D2 = self._sqdist_train(c, X)
        F, N = self.n_components, len(fc.T)
        mu = np.empty((len(X), F))
        V = np.empty((F, len(X), N))
        for f in range(F):
            self._kernel_from_sqdist(c, f, D2, out=V[f])
            mu[:, f] = V[f] @ fc.alpha[f] + self.mean[c, f]
            _whiten_rows(fc.L[f], V[f])
        return mu, V

    def kernel(self, c: int, f: int, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """k_{c,f}(A, B) without the white noise, by explicit differences (small blocks)."""
        A, B = np.asarray(A, float), np.asarray(B, float)
        diff = A[..., :, None, :] - B[..., None, :, :]
        return self.amplitude[c, f] * np.exp(-np.sum(diff * diff, axis=-1) / (2.0 * self.length_scale[c, f] ** 2))

    # -- predictive ---------------------------------------------------------------------------
    def predict(self, Xs) -> tuple[np.ndarray, np.ndarray]:
        """Joint predictive per trajectory: Xs (..., K, d) -> mu (..., C, F, K), cov (..., C, F, K, K).

        ``cov`` includes the white noise σ_n² I (test measurements carry it, docs/design.md §5), plus
        the test-domain variance δ² of ``with_test_variance`` (zero unless set).
        """
        Xs = np.asarray(Xs, dtype=float)
        if Xs.ndim < 2 or Xs.shape[-1] != self.input_dim:
            raise ValueError(f"predict: inputs must be (..., K, {self.input_dim}), got {Xs.shape}")
        if not np.all(np.isfinite(Xs)):
            raise ValueError("predict: inputs contain NaN or infinite values")
        lead, (K, d) = Xs.shape[:-2], Xs.shape[-2:]
        flat3 = np.ascontiguousarray(Xs.reshape(-1, K, d))
        B, C, F = len(flat3), self.n_classes, self.n_components
        flat = flat3.reshape(B * K, d)
        mu = np.empty((B, C, F, K))
        cov = np.empty((B, C, F, K, K))
        diff = flat3[:, :, None, :] - flat3[:, None, :, :]
        D2tt = np.einsum("bkld,bkld->bkl", diff, diff)          # within-trajectory distances
        kk = np.empty((B, K, K))
        for c in range(C):
            fc = self.factors()[c]
            N = len(fc.T)
            D2 = self._sqdist_train(c, flat)                      # (B·K, N), one GEMM per class
            V = np.empty_like(D2)
            for f in range(F):
                self._kernel_from_sqdist(c, f, D2, out=V)
                mu[:, c, f, :] = (V @ fc.alpha[f] + self.mean[c, f]).reshape(B, K)
                _whiten_rows(fc.L[f], V)                          # the dominant cost: O(B·K·N²)
                predictive_covariance(self, c, f, V.reshape(B, K, N), D2tt, kk, cov[:, c, f],
                                      self.instance_parameters(c, f))
        return mu.reshape(lead + (C, F, K)), cov.reshape(lead + (C, F, K, K))

    def marginal(self, X) -> tuple[np.ndarray, np.ndarray]:
        """Pointwise predictive mean and variance (incl. σ_n²): X (..., d) -> (..., C, F) each."""
        X = np.asarray(X, dtype=float)
        lead = X.shape[:-1]
        flat = np.ascontiguousarray(X.reshape(-1, X.shape[-1]))
        C, F = self.n_classes, self.n_components
        mu = np.empty((len(flat), C, F))
        var = np.empty((len(flat), C, F))
        for c in range(C):
            m, V = self.whitened(c, flat)
            mu[:, c] = m
            var[:, c] = self.amplitude[c] + self.test_noise[c] - np.einsum("fnj,fnj->nf", V, V)
        return mu.reshape(lead + (C, F)), var.reshape(lead + (C, F))

    # -- files -----------------------------------------------------------------------------------
    def hyperparameters(self) -> dict:
        """{class: {component: {mean, amplitude, length_scale, noise}}} as plain floats."""
        return {cls: {str(comp): {"mean": float(self.mean[c, f]), "amplitude": float(self.amplitude[c, f]),
                                  "length_scale": float(self.length_scale[c, f]),
                                  "noise": float(self.noise[c, f])}
                      for f, comp in enumerate(self.components)}
                for c, cls in enumerate(self.classes)}

    def digest(self, c: int | None = None, f: int | None = None, *, trained_only: bool = False) -> str:
        """The one content digest (``bank_index.content_digest``) of these models: of one GP (class
        ``c``, component ``f``: its inputs, targets and hyperparameters, and the test-domain noise
        unless ``trained_only``: what depends on the fit alone is shared by the calibrated variant)
        or, without ``c``, of every GP. The key of any cache that must not serve other models under
        the same names."""

        parts = []
        for ci in range(self.n_classes) if c is None else [c]:
            parts.append(self.X[ci])
            for fi in range(self.n_components) if f is None else [f]:
                parts.append(np.asarray(self.Y[ci][fi]))
                parts.append(np.array([self.mean[ci, fi], self.amplitude[ci, fi], self.length_scale[ci, fi],
                                       self.noise[ci, fi]] + ([] if trained_only else [self.test_noise[ci, fi]])))
        return content_digest(*parts)


def _whiten_rows(L: np.ndarray, V: np.ndarray) -> None:
    """In place: rows v of V (n, N, C-ordered) become L⁻¹ v, i.e. V <- V L⁻ᵀ (what scikit-learn's
    ``solve_triangular(L, K_trans.T)`` computes), as one BLAS triangular solve on all rows at once."""
    from scipy.linalg.blas import dtrsm

    out = dtrsm(1.0, L, V.T, side=0, lower=1, trans_a=0, diag=0, overwrite_b=1)
    if not np.shares_memory(out, V):  # pragma: no cover - BLAS wrapper made a copy after all
        V[...] = out.T
