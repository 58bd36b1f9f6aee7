"""The benches behind ``companion bench``: each measures in one run and reports ratios."""
