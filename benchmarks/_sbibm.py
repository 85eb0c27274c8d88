"""sbibm's own observations, reference posterior samples and C2ST, for the benchmarks.

The files ship inside the ``sbibm`` wheel on the package registry. It is downloaded without
dependencies at benchmark time into a cache folder (never committed) and read from the zip;
sbibm itself (and its torch-era dependency pins) is not installed. C2ST is sbibm's
``sbibm.metrics.c2st`` line for line: z-score both sets with the reference's mean and std
(ddof = 1), scikit-learn ``MLPClassifier`` (ReLU, two hidden layers of 10·dim, adam,
``max_iter=10000``, ``random_state=seed``), 5-fold shuffled ``KFold``, mean accuracy.
Needs the ``bench`` optional dependencies (scikit-learn).
"""

import bz2
import functools
import glob
import io
import os
import subprocess
import sys
import zipfile

import numpy as np

SBIBM_VERSION = "1.1.0"
CACHE = os.environ.get("VDSBI_SBIBM_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "vdsbi-sbibm"))


@functools.lru_cache(maxsize=1)
def _wheel(cache: str = CACHE) -> zipfile.ZipFile:
    found = glob.glob(os.path.join(cache, f"sbibm-{SBIBM_VERSION}-*.whl"))
    if not found:
        os.makedirs(cache, exist_ok=True)
        print(f"downloading the sbibm {SBIBM_VERSION} wheel (no dependencies) into {cache}", flush=True)
        cmd = [
            sys.executable,
            "-m",
            "pip",
            "download",
            f"sbibm=={SBIBM_VERSION}",
            "--no-deps",
            "-d",
            cache,
            "-q",
        ]
        subprocess.run(cmd, check=True)
        found = glob.glob(os.path.join(cache, f"sbibm-{SBIBM_VERSION}-*.whl"))
    return zipfile.ZipFile(found[0])


def _csv(task: str, num: int, name: str) -> np.ndarray:
    path = f"sbibm/tasks/{task}/files/num_observation_{num}/{name}"
    raw = _wheel().read(path)
    if name.endswith(".bz2"):
        raw = bz2.decompress(raw)
    return np.loadtxt(io.StringIO(raw.decode()), delimiter=",", skiprows=1, ndmin=2).astype(np.float32)


def observation(task: str, num: int) -> np.ndarray:
    """sbibm's observation ``num`` (1..10) of ``task``, shape ``(dim_x,)``."""
    return _csv(task, num, "observation.csv")[0]


def true_parameters(task: str, num: int) -> np.ndarray:
    return _csv(task, num, "true_parameters.csv")[0]


def reference_posterior_samples(task: str, num: int) -> np.ndarray:
    """sbibm's 10 000 reference posterior samples for observation ``num``."""
    return _csv(task, num, "reference_posterior_samples.csv.bz2")


def c2st(
    reference: np.ndarray, samples: np.ndarray, seed: int = 1, n_folds: int = 5, n_jobs: int = 1
) -> float:
    """sbibm's C2ST accuracy (see the module docstring); 0.5 = indistinguishable.

    BLAS runs on one thread: the MLP's float rounding depends on the BLAS thread count, and
    hundreds of Adam epochs amplify it (10-d gaussian_linear_uniform, 2 threads vs 1: fold
    accuracies apart by up to 0.03), so one thread makes the figure independent of the
    machine. ``n_jobs`` > 1 fits the folds in parallel processes (``cross_val_score``'s own
    option, not in sbibm's call), each on one BLAS thread: same classifier, folds and data, so
    the same fold scores as ``n_jobs=1``; only the wall time changes.
    """
    from joblib import parallel_config
    from sklearn.model_selection import KFold, cross_val_score
    from sklearn.neural_network import MLPClassifier
    from threadpoolctl import threadpool_limits

    X, Y = np.asarray(reference, np.float32), np.asarray(samples, np.float32)
    mean, std = X.mean(0), X.std(0, ddof=1)
    X, Y = (X - mean) / std, (Y - mean) / std
    ndim = X.shape[1]
    clf = MLPClassifier(
        activation="relu",
        hidden_layer_sizes=(10 * ndim, 10 * ndim),
        max_iter=10000,
        solver="adam",
        random_state=seed,
    )
    data = np.concatenate((X, Y))
    target = np.concatenate((np.zeros((X.shape[0],)), np.ones((Y.shape[0],))))
    shuffle = KFold(n_splits=n_folds, shuffle=True, random_state=seed)
    with threadpool_limits(1), parallel_config(backend="loky", inner_max_num_threads=1):
        scores = cross_val_score(clf, data, target, cv=shuffle, scoring="accuracy", n_jobs=n_jobs)
    return float(np.asarray(np.mean(scores)).astype(np.float32))
