"""Flight logs: CSV writer (writer thread), readers, and plots."""

from companion.flightlog.csv_file import read_csv
from companion.flightlog.csvlog import CsvLog

__all__ = ["CsvLog", "read_csv"]
