"""Shipped parameter sets (installed as ``companion_params``)."""
