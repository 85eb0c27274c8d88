"""Benchmarks of vdsbi: scripts, their helpers and the sbibm tasks (`benchmarks.tasks`)."""
