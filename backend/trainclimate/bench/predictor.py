"""``bench predictor``: the Transient Predictor's streaming fit time and peak memory at 1-min
sampling, against materialising the whole Hankel matrix for one QR."""

from __future__ import annotations

from pathlib import Path

from trainclimate.bench.common import child, machine

#: The streaming fit's extra memory at the largest scale may be at most this many times the
#: smallest's (at least 1 MB). [-]
TARGET_MEMORY_GROWTH = 1.5


def run(
    scales: tuple[int, ...] = (1, 10, 100),
    data_dir: str | Path | None = None,
    rho: int = 60,
    horizon: int = 30,
    progress=None,
) -> dict:
    """Transient Predictor fit time (s) and peak memory (MB) at 1-min sampling, ρ = 60, T = 30.

    The streaming fit runs on the full 1-min dataset (every trajectory of both campaigns, from
    ``data_dir``, default the cached default dataset) and on the same trajectories repeated
    ``scales`` times (as many more Hankel columns); the baseline, at 1×, materialises the whole
    transposed Hankel matrix and factors it in one QR. Each run is a fresh process reporting its
    own peak resident memory (which includes the loaded trajectories and libraries,
    ``rss_before_fit_mb``). ``progress(1)`` is called after each fit.
    """
    from trainclimate.data.cache import default_dataset

    path = Path(data_dir or default_dataset()) / "trajectories_1min.parquet"
    runs = []
    for mode, scale in [("one_shot", 1), *(("streaming", s) for s in scales)]:
        runs.append(child("run_fit", str(path), mode, str(scale), str(rho), str(horizon)))
        if progress:
            progress(1)
    one_shot = runs[0]
    streaming = {r["scale"]: r for r in runs[1:]}
    first = streaming[scales[0]]
    extra = {s: r["peak_rss_mb"] - r["rss_before_fit_mb"] for s, r in streaming.items()}
    return {
        "rho": rho,
        "horizon": horizon,
        "rows": 9 * (rho + horizon),
        "fit_seconds": first["seconds"],
        "columns": first["columns"],
        "runs": runs,
        "streaming_vs_one_shot_time": first["seconds"] / one_shot["seconds"],
        "one_shot_extra_mb": one_shot["peak_rss_mb"] - one_shot["rss_before_fit_mb"],
        "streaming_extra_mb": extra,
        "seconds_per_million_columns": {
            s: r["seconds"] / r["columns"] * 1e6 for s, r in streaming.items()
        },
        # memory proportional to rows², not columns: the largest fit takes no more than the
        # smallest (plus a margin for the allocator)
        "target": {"streaming_extra_mb_growth_max": TARGET_MEMORY_GROWTH},
        "target_met": max(extra.values()) <= TARGET_MEMORY_GROWTH * max(min(extra.values()), 1.0),
        "machine": machine(),
    }


def text(d: dict) -> str:
    """One line per fit: mode, scale, Hankel columns, s, peak MB and the MB the fit added."""
    return "\n".join(
        f"{r['mode']:>9} ×{r['scale']:<4} {r['columns']:>10,} columns "
        f"{r['seconds']:8.1f} s  peak {r['peak_rss_mb']:7.0f} MB "
        f"(+{r['peak_rss_mb'] - r['rss_before_fit_mb']:.0f} MB for the fit)"
        for r in d["runs"]
    )
