"""`vdsbi sample DIR --n K`: draw from a saved estimator (any process, any time)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..io._errors import InputError


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "sample",
        help="draw K posterior samples from the estimator `identify` saved in DIR",
        description="Reload DIR/estimator.npz and print (or write) K samples as CSV.",
    )
    p.add_argument("dir", metavar="DIR", help="an `identify` output directory")
    p.add_argument("--n", type=int, required=True, metavar="K", help="number of samples")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--out", metavar="CSV", help="write here instead of stdout")
    return p


def run(args) -> int:
    import jax
    import numpy as np
    import pandas as pd

    from ..api import ESTIMATOR
    from ..inference import Posterior
    from ..simulator import PARAM_NAMES

    path = Path(args.dir) / ESTIMATOR
    if not path.is_file():
        raise InputError(path, "DIR", "no estimator here; run `vdsbi identify` first")
    if args.n < 1:
        raise InputError("settings", "--n", f"must be >= 1, got {args.n}")
    try:
        post = Posterior.load(path)
    except Exception as err:  # corrupt or foreign file
        raise InputError(path, "estimator", f"cannot be read ({type(err).__name__}: {err})") from None
    samples = np.asarray(post.sample(jax.random.key(args.seed), args.n))
    names = post.prior.names or PARAM_NAMES
    df = pd.DataFrame(samples, columns=list(names))
    if args.out:
        df.to_csv(args.out, index=False, float_format="%.9g")
    else:
        df.to_csv(sys.stdout, index=False, float_format="%.9g")
    return 0
