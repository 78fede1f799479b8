"""The numpy joint classifier: learns separable classes, reports honestly, checks input."""

import json

import numpy as np
import pytest

from shinysim.recon.classify import (
    CLASSIFIER_METHODS,
    JointClassifier,
    accuracy,
    confusion_matrix,
    feature_matrix,
    train_classifier,
)

CLASSES = ("good", "insufficient", "excess")


def blobs(rng, n, centres, spread=0.3):
    X = np.concatenate([c + spread * rng.standard_normal((n, len(c))) for c in centres])
    y = np.repeat(CLASSES[: len(centres)], n)
    return X, y


@pytest.mark.parametrize("method", CLASSIFIER_METHODS)
def test_separable_classes_are_learned_and_held_out_points_classified(method):
    rng = np.random.default_rng(0)
    centres = [np.array([0.0, 0.0, 5.0]), np.array([3.0, 0.0, 5.0]), np.array([0.0, 3.0, 5.0])]
    Xtr, ytr = blobs(rng, 30, centres)
    Xte, yte = blobs(np.random.default_rng(1), 20, centres)
    # scale one feature by 1000: standardisation must make this irrelevant
    Xtr[:, 1] *= 1000
    Xte[:, 1] *= 1000
    clf = train_classifier(Xtr, ytr, method=method, classes=CLASSES)
    assert accuracy(yte, clf.predict(Xte)) == 1.0
    p = clf.predict_proba(Xte)
    assert p.shape == (60, 3) and np.allclose(p.sum(axis=1), 1.0)


def test_logistic_handles_classes_a_centroid_cannot():
    """Two classes share a mean in every feature but one direction: a linear boundary, no centroid gap."""
    rng = np.random.default_rng(3)
    n = 200
    X = rng.standard_normal((n, 2)) * [5.0, 1.0]
    y = np.where(X[:, 0] + 0.2 * X[:, 1] > 0, "good", "excess")
    clf = train_classifier(X, y, method="logistic", l2=1e-4)
    Xt = rng.standard_normal((n, 2)) * [5.0, 1.0]
    yt = np.where(Xt[:, 0] + 0.2 * Xt[:, 1] > 0, "good", "excess")
    assert accuracy(yt, clf.predict(Xt)) > 0.95


def test_confusion_matrix_and_accuracy():
    y_true = ["good", "good", "excess", "insufficient", "excess"]
    y_pred = ["good", "excess", "excess", "insufficient", "good"]
    cm = confusion_matrix(y_true, y_pred, CLASSES)
    assert cm.tolist() == [[1, 0, 1], [0, 1, 0], [1, 0, 1]]
    assert cm.sum() == 5
    assert accuracy(y_true, y_pred) == pytest.approx(3 / 5)
    assert np.isnan(accuracy([], []))
    with pytest.raises(ValueError, match="not among classes"):
        confusion_matrix(["bridge"], ["good"], CLASSES)


def test_round_trip_and_nan_features():
    rng = np.random.default_rng(5)
    X, y = blobs(rng, 15, [np.zeros(2), np.full(2, 4.0)])
    X[0, 1] = np.nan  # a missing feature in training
    clf = train_classifier(X, y, feature_names=["a", "b"])
    again = JointClassifier.from_dict(json.loads(clf.to_json()))
    Xq = np.array([[0.1, np.nan], [4.2, 3.9], [np.inf, 0.0]])
    assert (clf.predict(Xq) == again.predict(Xq)).all()
    assert clf.predict(Xq)[1] == "insufficient"


def test_feature_matrix_orders_columns():
    F = feature_matrix([{"b": 2.0, "a": 1.0}, {"a": 3.0}], ["a", "b"])
    assert F.shape == (2, 2)
    assert F[0].tolist() == [1.0, 2.0] and F[1, 0] == 3.0 and np.isnan(F[1, 1])


def test_training_input_checks():
    X = np.zeros((4, 2))
    with pytest.raises(ValueError, match="method must be one of"):
        train_classifier(X, ["good"] * 4, method="svm")
    with pytest.raises(ValueError, match="must be \\(N, F\\)"):
        train_classifier(X, ["good"] * 3)
    with pytest.raises(ValueError, match=r"classes \['excess'\] have no training examples"):
        train_classifier(X, ["good"] * 4, classes=["good", "excess"])
    with pytest.raises(ValueError, match="not among classes"):
        train_classifier(X, ["good", "good", "bridge", "good"], classes=["good"])
    clf = train_classifier(X, ["good", "good", "excess", "excess"])
    with pytest.raises(ValueError, match="X must have shape"):
        clf.predict(np.zeros((2, 3)))
