"""SB3 loggers for training runs: stdout, CSV and tensorboard, with a CSV that a resumed run extends."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

from stable_baselines3.common.logger import CSVOutputFormat, HumanOutputFormat, KVWriter, Logger, TensorBoardOutputFormat

PROGRESS_CSV = "progress.csv"


class AppendingCSVOutputFormat(CSVOutputFormat):
    """SB3's CSV writer, continuing an existing file: rows of earlier sessions are kept and new
    columns are back-filled into them (SB3 rewrites the file in place, which only grows), so a
    resumed run has one ``progress.csv``."""

    def __init__(self, filename: str | Path):
        self.file = open(filename, "r+" if Path(filename).exists() else "w+")
        self.file.seek(0)
        header = self.file.readline().strip()
        self.keys = next(csv.reader([header])) if header else []
        self.file.seek(0, 2)
        self.separator = ","
        self.quotechar = '"'


def make_run_logger(folder: str | Path, formats: tuple[str, ...] = ("stdout", "csv", "tensorboard")) -> Logger:
    """A logger writing ``formats`` under ``folder``; the CSV appends to an earlier run's file."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    writers: list[KVWriter] = []
    for fmt in formats:
        if fmt == "stdout":
            writers.append(HumanOutputFormat(sys.stdout))
        elif fmt == "csv":
            writers.append(AppendingCSVOutputFormat(folder / PROGRESS_CSV))
        elif fmt == "tensorboard":
            writers.append(TensorBoardOutputFormat(str(folder / "tensorboard")))
        else:
            raise ValueError(f"unknown log format {fmt!r}; expected some of 'stdout', 'csv', 'tensorboard'")
    return Logger(folder=str(folder), output_formats=writers)
