"""`sample`: draws from the neural estimator `identify` saved."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..io import InputError
from .outputs import ESTIMATOR


def sample(run_dir: str | os.PathLike, n: int, *, seed: int = 0):
    """`n` draws from the estimator `identify` saved in `run_dir`, as a DataFrame (one column per
    parameter).

    Raises:
        InputError: no readable estimator in `run_dir`, or `n` < 1.
    """
    import jax
    import pandas as pd

    from ..inference import Posterior
    from ..simulator import PARAM_NAMES

    path = Path(run_dir) / ESTIMATOR
    if not path.is_file():
        raise InputError(path, "DIR", "no estimator here; run `vdsbi identify` first")
    if n < 1:
        raise InputError("settings", "--n", f"must be >= 1, got {n}")
    try:
        post = Posterior.load(path)
    except Exception as err:  # corrupt or foreign file
        raise InputError(path, "estimator", f"cannot be read ({type(err).__name__}: {err})") from None
    samples = np.asarray(post.sample(jax.random.key(seed), n))
    return pd.DataFrame(samples, columns=list(post.prior.names or PARAM_NAMES))
