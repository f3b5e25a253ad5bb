"""Reading run artefacts (docs/ARTEFACTS.md): CSV files whose last row may be torn when a
process was killed mid-write."""
import os


def read_csv(path):
    """Every complete row of a CSV as a dict of strings (a torn final line is skipped)."""
    rows = []
    try:
        with open(path, errors="replace") as f:
            header = f.readline().strip().split(",")
            for line in f:
                if not line.endswith("\n"):
                    break
                values = line.strip().split(",")
                if len(values) == len(header):
                    rows.append(dict(zip(header, values)))
    except OSError:
        pass
    return rows


def last_row(path):
    """The last complete row of a CSV (None if none yet), reading only its tail."""
    try:
        with open(path, "rb") as f:
            header = f.readline().decode(errors="replace").strip().split(",")
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - 4096))
            tail = f.read().decode(errors="replace")
    except OSError:
        return None
    lines = tail.split("\n")
    lines = lines[:-1]  # what follows the last newline is a row being written (or nothing)
    for line in reversed(lines):
        values = line.split(",")
        if len(values) == len(header) and values[0] != header[0]:
            return dict(zip(header, values))
    return None
