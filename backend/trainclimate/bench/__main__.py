"""The child processes of the benchmarks: ``python -m trainclimate.bench NAME ARG…`` runs
``NAME(*ARGS)`` of this module and prints its result as one line of JSON.

Each child is a fresh process, so the peak resident memory it reports is its own. It loads the
same libraries as the benchmarks' parent module did before the benchmarks were split into modules
(numpy, the fleet simulator and its scenarios), so its peak memory figures stay comparable with
the earlier ones in ``docs/benchmarks.md`` (most of those MB are the imported libraries).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from trainclimate.bench.common import peak_rss_mb
from trainclimate.bench.replicas import run_replica
from trainclimate.sim import scenarios, simulator  # noqa: F401  (loaded in every child: see above)


def run_pipeline(raw: str, out: str) -> dict:
    """The pipeline on the raw logs under ``raw``, writing to ``out``: its time in s, the raw
    rows and coach-days read, and the process's peak memory in MB."""
    from trainclimate.data.dataset import build_dataset

    t0 = time.perf_counter()
    summary = build_dataset(raw, out)
    return {
        "seconds": time.perf_counter() - t0,
        "raw_rows": summary.raw_rows,
        "coach_days": summary.coach_days,
        "peak_rss_mb": peak_rss_mb(),
    }


def run_parse_only(raw: str) -> dict:
    """The pipeline's baseline: only parse every CSV file under ``raw`` with pandas; the time in
    s and the rows parsed."""
    import pandas as pd

    t0 = time.perf_counter()
    rows = 0
    for path in sorted(Path(raw).rglob("*.csv")):
        sep = ";" if b";" in path.read_bytes()[:200] else ","
        try:
            rows += len(pd.read_csv(path, sep=sep, dtype=str, on_bad_lines="skip"))
        except (ValueError, UnicodeDecodeError):
            continue  # the unreadable files the pipeline also skips
    return {"seconds": time.perf_counter() - t0, "rows": rows}


def run_fit(path: str, mode: str, scale: str, rho: str, horizon: str) -> dict:
    """A Transient Predictor fit on the trajectories of ``path`` repeated ``scale`` times
    (``mode`` ``streaming``), or the baseline ``one_shot``: the whole transposed Hankel matrix
    materialised and factored in one QR. The Hankel columns, the fit's time in s, the process's
    peak memory in MB and its resident memory before the fit in MB."""
    import itertools

    import scipy.linalg as sla

    from trainclimate.data.trajectory import read_trajectories
    from trainclimate.predict import TransientPredictor
    from trainclimate.predict.base import Z_SCALE
    from trainclimate.predict.hankel import column_chunks

    scale, rho, horizon = int(scale), int(rho), int(horizon)
    trajs = read_trajectories(path)
    before = peak_rss_mb()
    t0 = time.perf_counter()
    if mode == "streaming":
        repeated = itertools.chain.from_iterable(itertools.repeat(trajs, scale))
        columns = TransientPredictor(rho, horizon).fit(repeated).n_columns
    else:
        zt = np.concatenate(list(column_chunks(trajs, rho + horizon)))
        zt /= np.tile(Z_SCALE, rho + horizon)
        columns = len(zt)
        sla.qr(zt, mode="r", overwrite_a=True)
    return {
        "mode": mode,
        "scale": scale,
        "columns": columns,
        "seconds": time.perf_counter() - t0,
        "peak_rss_mb": peak_rss_mb(),
        "rss_before_fit_mb": before,
    }


CHILDREN = {
    "run_pipeline": run_pipeline,
    "run_parse_only": run_parse_only,
    "run_fit": run_fit,
    "run_replica": run_replica,  # a service replica of ``bench replicas``
}

if __name__ == "__main__":
    print(json.dumps(CHILDREN[sys.argv[1]](*sys.argv[2:])))
