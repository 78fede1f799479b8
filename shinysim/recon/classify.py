r"""Solder-defect classification from joint features, in numpy.

The features are those of :func:`shinysim.recon.joint.joint_features`; the
classifier (:data:`CLASSIFIER_METHODS`) is learned from labelled joints by
:func:`train_classifier`, which sees only the training joints:
``"logistic"``, a multinomial logistic regression with an L2 penalty fitted
by Newton's method, or ``"nearest-centroid"``, the baseline. How, and why:
``docs/solder.md``, section "Classification".
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from ..errors import OptionError

__all__ = [
    "CLASSIFIER_METHODS",
    "JointClassifier",
    "train_classifier",
    "confusion_matrix",
    "confusion_report",
    "accuracy",
    "feature_matrix",
]

#: Learning methods of :func:`train_classifier`.
CLASSIFIER_METHODS = ("logistic", "nearest-centroid")


def feature_matrix(features, names):
    """(N, F) float array from a list of feature dicts, columns in ``names`` order."""
    return np.array([[float(f.get(n, np.nan)) for n in names] for f in features], dtype=float).reshape(-1, len(names))


#: The array fields of a :class:`JointClassifier`, in the order of its :meth:`~JointClassifier.to_dict`.
_ARRAYS = ("mean", "scale", "weights", "centroids")


@dataclass
class JointClassifier:
    """A trained classifier.

    Attributes
    ----------
    method : str
    classes : tuple of str
    feature_names : tuple of str
    mean, scale : (F,) ndarray
        Standardisation: ``(X - mean) / scale``.
    weights : (F + 1, C) ndarray or None
        Logistic regression coefficients (last row: intercepts).
    centroids : (C, F) ndarray or None
        Class means of the standardised features.
    """

    method: str
    classes: tuple
    feature_names: tuple
    mean: np.ndarray
    scale: np.ndarray
    weights: np.ndarray | None = None
    centroids: np.ndarray | None = None

    def _standardise(self, X):
        X = np.asarray(X, dtype=float)
        if X.ndim != 2 or X.shape[1] != len(self.feature_names):
            raise OptionError(f"X must have shape (N, {len(self.feature_names)}), got {X.shape}")
        Z = (X - self.mean) / self.scale
        return np.where(np.isfinite(Z), Z, 0.0)

    def decision(self, X):
        """(N, C) class scores (log-probabilities up to a constant, or minus squared distances)."""
        Z = self._standardise(X)
        if self.method == "logistic":
            return np.column_stack([Z, np.ones(len(Z))]) @ self.weights
        return -np.sum((Z[:, None, :] - self.centroids[None]) ** 2, axis=-1)

    def predict_proba(self, X):
        """(N, C) class probabilities (softmax of :meth:`decision`)."""
        s = self.decision(X)
        s = s - s.max(axis=1, keepdims=True)
        p = np.exp(s)
        return p / p.sum(axis=1, keepdims=True)

    def predict(self, X):
        """(N,) predicted class names."""
        return np.asarray(self.classes, dtype=object)[np.argmax(self.decision(X), axis=1)]

    def to_dict(self):
        """JSON-ready description (reload with :meth:`from_dict`)."""
        d = {"method": self.method, "classes": list(self.classes), "feature_names": list(self.feature_names)}
        d.update({k: getattr(self, k).tolist() for k in _ARRAYS if getattr(self, k) is not None})
        return d

    @classmethod
    def from_dict(cls, d):
        return cls(d["method"], tuple(d["classes"]), tuple(d["feature_names"]), np.asarray(d["mean"], float),
                   np.asarray(d["scale"], float), **{k: np.asarray(d[k], float) for k in _ARRAYS[2:] if k in d})

    def to_json(self):
        return json.dumps(self.to_dict(), indent=2)


def _fit_logistic(Z, Y, l2, max_iter, tol):
    """Multinomial logistic regression by Newton's method.

    Z : (N, F) standardised features; Y : (N, C) one-hot. Minimises the mean
    cross-entropy plus ``l2/2 * |W|^2`` (intercepts not penalised). The last
    class's coefficients are fixed at 0 (identifiable softmax).
    """
    N, F = Z.shape
    C = Y.shape[1]
    A = np.column_stack([Z, np.ones(N)])
    D = F + 1
    W = np.zeros((D, C))
    pen = np.full(D, l2)
    pen[-1] = 0.0
    free = C - 1
    for _ in range(max_iter):
        S = A @ W
        S -= S.max(axis=1, keepdims=True)
        P = np.exp(S)
        P /= P.sum(axis=1, keepdims=True)
        G = (A.T @ (P - Y)) / N + pen[:, None] * W          # (D, C)
        g = G[:, :free].T.reshape(-1)                         # class-major
        H = np.zeros((free * D, free * D))
        for a in range(free):
            for b in range(free):
                wab = P[:, a] * ((a == b) - P[:, b])
                blk = (A * wab[:, None]).T @ A / N
                if a == b:
                    blk += np.diag(pen)
                H[a * D:(a + 1) * D, b * D:(b + 1) * D] = blk
        H += 1e-10 * np.eye(free * D)
        step = np.linalg.solve(H, g)
        W[:, :free] -= step.reshape(free, D).T
        if np.max(np.abs(step)) < tol:
            break
    return W


def train_classifier(X, y, *, method="logistic", feature_names=None, classes=None, l2=0.01, max_iter=100,
                     tol=1e-8):
    """Learn a joint classifier from labelled feature vectors.

    Parameters
    ----------
    X : (N, F) array_like
        Features (non-finite entries are replaced by the training mean).
    y : (N,) array_like of str
        Class labels.
    method : {"logistic", "nearest-centroid"}
    feature_names : sequence of str, optional
        Column names (default ``f0, f1, ...``).
    classes : sequence of str, optional
        Class order (default: sorted labels of ``y``).
    l2 : float
        L2 penalty of the logistic regression, on standardised features.

    Returns
    -------
    JointClassifier

    Raises
    ------
    ValueError
        Unknown method, mismatched shapes, a class without examples, or a
        label outside ``classes``.
    """
    if method not in CLASSIFIER_METHODS:
        raise OptionError(f"method must be one of {CLASSIFIER_METHODS}, got {method!r}")
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=object)
    if X.ndim != 2 or len(X) != len(y):
        raise OptionError(f"X must be (N, F) with N = len(y) = {len(y)}, got {X.shape}")
    if not (np.isfinite(l2) and l2 >= 0):
        raise OptionError(f"l2 must be >= 0, got {l2!r}")
    classes = tuple(sorted(set(y.tolist()))) if classes is None else tuple(classes)
    unknown = sorted(set(y.tolist()) - set(classes))
    if unknown:
        raise OptionError(f"labels {unknown} are not among classes {classes}")
    missing = [c for c in classes if not np.any(y == c)]
    if missing:
        raise OptionError(f"classes {missing} have no training examples")
    names = tuple(feature_names) if feature_names is not None else tuple(f"f{i}" for i in range(X.shape[1]))
    if len(names) != X.shape[1]:
        raise OptionError(f"{len(names)} feature names for {X.shape[1]} columns")
    finite = np.isfinite(X)
    cnt = finite.sum(axis=0)
    mean = np.where(cnt > 0, np.where(finite, X, 0.0).sum(axis=0) / np.maximum(cnt, 1), 0.0)
    Xf = np.where(finite, X, mean)
    scale = Xf.std(axis=0)
    scale = np.where(scale > 1e-12, scale, 1.0)
    Z = (Xf - mean) / scale
    Y = (y[:, None] == np.asarray(classes, dtype=object)[None, :]).astype(float)
    clf = JointClassifier(method, classes, names, mean, scale)
    if method == "logistic":
        clf.weights = _fit_logistic(Z, Y, l2, max_iter, tol)
    else:
        clf.centroids = (Y.T @ Z) / Y.sum(axis=0)[:, None]
    return clf


def confusion_matrix(y_true, y_pred, classes):
    """(C, C) int counts: row = true class, column = predicted class."""
    classes = list(classes)
    index = {c: i for i, c in enumerate(classes)}
    m = np.zeros((len(classes), len(classes)), dtype=int)
    for t, p in zip(y_true, y_pred):
        if t not in index or p not in index:
            raise OptionError(f"label {t if t not in index else p!r} is not among classes {classes}")
        m[index[t], index[p]] += 1
    return m


def confusion_report(y_true, y_pred, classes):
    """:func:`confusion_matrix` as a report's JSON entry: the classes, what rows and columns are, the counts."""
    return {"classes": list(classes), "rows": "true class", "columns": "predicted class",
            "counts": confusion_matrix(y_true, y_pred, classes).tolist()}


def accuracy(y_true, y_pred):
    """Fraction of equal labels (NaN for no labels)."""
    y_true = np.asarray(y_true, dtype=object)
    y_pred = np.asarray(y_pred, dtype=object)
    if y_true.shape != y_pred.shape:
        raise OptionError(f"y_true and y_pred differ in shape: {y_true.shape} vs {y_pred.shape}")
    return float(np.mean(y_true == y_pred)) if y_true.size else float("nan")
