"""`diagnose`: find, name and fix model mismatch (`vdsbi.discovery.diagnose`)."""

from __future__ import annotations


def diagnose(*args, **kwargs):
    """`vdsbi.discovery.diagnose`, imported on first use (it pulls in the discovery layer)."""
    from ..discovery import diagnose as _diagnose

    return _diagnose(*args, **kwargs)
