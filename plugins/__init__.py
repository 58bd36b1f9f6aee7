"""Hardware and payload drivers (installed as ``companion_plugins``), found through entry points."""
