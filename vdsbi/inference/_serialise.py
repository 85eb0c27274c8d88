"""One-file, atomic storage: a ``.npz`` holding a JSON header, arrays and a serialised flow."""

import io
import json
import os
import tempfile
from typing import Any

import equinox as eqx
import numpy as np

from ._estimator import AbstractEstimator
from ._flow import flow_from_spec
from ._flow_matching import fmpe_from_spec

FORMAT_VERSION = 1


def flow_to_bytes(flow: AbstractEstimator) -> np.ndarray:
    buf = io.BytesIO()
    eqx.tree_serialise_leaves(buf, flow)
    return np.frombuffer(buf.getvalue(), dtype=np.uint8)


def flow_from_bytes(spec: dict[str, Any], data: np.ndarray) -> AbstractEstimator:
    """The estimator (spline flow or `FlowMatchingEstimator`) described by ``spec``."""
    skeleton = fmpe_from_spec(spec) if spec.get("estimator") == "fmpe" else flow_from_spec(spec)
    return eqx.tree_deserialise_leaves(io.BytesIO(np.asarray(data, np.uint8).tobytes()), skeleton)


def write_npz(path, header: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """Write ``header`` (JSON) and ``arrays`` to ``path`` atomically (temp file + ``os.replace``)."""
    path = os.fspath(path)
    payload = {"__header__": np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)}
    payload.update({k: np.asarray(v) for k, v in arrays.items()})
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(path)), suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **payload)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def read_npz(path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    with np.load(os.fspath(path), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(arrays.pop("__header__").tobytes().decode())
    return header, arrays
