"""vdsbi: vehicle-dynamics identification by simulation-based inference, in JAX."""

__version__ = "0.1.0"
