"""Flight logs: CSV writer (writer thread), readers, and plots."""

from companion.flightlog.csvlog import CsvLog, read_csv

__all__ = ["CsvLog", "read_csv"]
