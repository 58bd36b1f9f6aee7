"""companion: a MAVLink companion-computer application for precision parcel delivery.

See docs/architecture.md (layers, frames, rates, safety contract, paper equations) and README.md.
"""

__version__ = "0.1.0"
