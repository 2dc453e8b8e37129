"""A session's results (the files `dropfit run` writes, docs/formats.md) as
numpy arrays: from an output folder (read_results) or straight from a run
in memory (run)."""
import csv
import io
import json
import os

import numpy as np

from ._dropfit import parse_fit, run_session


def _table(text):
    """A CSV with a header row: {column: array}; numeric columns as float
    arrays (NaN kept), the others as lists of strings."""
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        return {}
    header, body = rows[0], rows[1:]
    columns = {}
    for j, name in enumerate(header):
        values = [r[j] if j < len(r) else "" for r in body]
        try:
            columns[name] = np.array([float(v) if v not in ("", "null") else np.nan for v in values])
        except ValueError:
            columns[name] = values
    return columns


class Results:
    """The results of one session run.

    summary: summary.csv ({column: array}, one entry per trial);
    trials: {trial id: trial.json as a dict}; trial_series: {trial id:
    trials/TRIAL/series.csv as {column: array}}; fit: the canonical fit.json
    as a dropfit.Fit, fit_json its whole dict; series: {trial id:
    series/TRIAL.csv beside it}; fits: {"model1": dict of fits/model1/fit.json,
    ...}; diagnosis: diagnosis.json (None when the loop did not run); files:
    every file's bytes by relative path.
    """

    def __init__(self, files, run_summary=None):
        self.files = dict(files)
        self.run_summary = run_summary
        text = {k: v.decode("utf-8") for k, v in self.files.items() if k.endswith((".csv", ".json"))}
        self.summary = _table(text["summary.csv"]) if "summary.csv" in text else {}
        self.trials, self.trial_series, self.series, self.fits = {}, {}, {}, {}
        for path, body in text.items():
            parts = path.split("/")
            if len(parts) == 3 and parts[0] == "trials" and parts[2] == "trial.json":
                self.trials[parts[1]] = json.loads(body)
            elif len(parts) == 3 and parts[0] == "trials" and parts[2] == "series.csv":
                self.trial_series[parts[1]] = _table(body)
            elif len(parts) == 2 and parts[0] == "series" and parts[1].endswith(".csv"):
                self.series[parts[1][:-4]] = _table(body)
            elif len(parts) == 3 and parts[0] == "fits" and parts[2] == "fit.json":
                self.fits[parts[1]] = json.loads(body)
        self.fit_json = json.loads(text["fit.json"]) if "fit.json" in text else None
        self.fit = parse_fit(text["fit.json"]) if "fit.json" in text else None
        self.diagnosis = json.loads(text["diagnosis.json"]) if "diagnosis.json" in text else None

    def __repr__(self):
        n = len(self.summary.get("trial", []))
        return f"Results({n} trials, fit={self.fit!r})"


def read_results(out_dir):
    """The results a run wrote to out_dir."""
    files = {}
    for root, _, names in os.walk(out_dir):
        for name in names:
            path = os.path.join(root, name)
            with open(path, "rb") as f:
                files[os.path.relpath(path, out_dir).replace(os.sep, "/")] = f.read()
    if "summary.csv" not in files:
        raise FileNotFoundError(f"{out_dir}: no summary.csv (not a dropfit output folder)")
    return Results(files)


def run(session_dir, out_dir=None, diagnose=True, threads=1):
    """Runs one session as `dropfit run` does and returns its Results; the
    files are written to out_dir (whole or not at all) when it is given."""
    r = run_session(os.fspath(session_dir), os.fspath(out_dir) if out_dir else "", diagnose, threads)
    files = r.pop("files")
    return Results(files, run_summary=r)
