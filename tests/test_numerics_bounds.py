"""The float32 error bound of the RBF SVM's decisions stays finite far from every support vector
(there the kernel is 0 and the old kern * expm1(...) gave NaN and a RuntimeWarning in `handover verify`)."""

import warnings

import numpy as np
from sklearn.svm import SVC

from trainer.numerics import svm_decision_bounds


def test_rbf_bound_is_finite_and_quiet_far_from_the_support_vectors():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(60, 5))
    y = np.repeat([0, 1, 2], 20)
    X[y == 1] += 3
    X[y == 2] -= 3
    svm = SVC(kernel="rbf", gamma=1.0, C=10).fit(X, y)
    near = X[:3]
    far = np.full((2, 5), 1e6)  # a stress case: saturated input, standardised far out
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bounds = svm_decision_bounds(svm, np.vstack([near, far]))
    assert np.isfinite(bounds).all() and (bounds >= 0).all()
    # near the data the bound is the usual tiny float32 bound, far away the kernel terms vanish
    assert bounds.max() < 1e-3
