"""Flight logs: CSV writer (writer thread), readers, and plots."""

from companion.flightlog.csv_file import read_csv
from companion.flightlog.csvlog import CsvLog
from companion.flightlog.reader import read_columns

__all__ = ["CsvLog", "read_columns", "read_csv"]
