"""companion: a MAVLink companion-computer application for precision parcel delivery.

See ../shared/DESIGN.md (layout, frames, rates, safety contract) and README.md.
"""

__version__ = "0.1.0"
