"""What several benchmarks share: the machine description every result carries, peak resident
memory, percentiles in milliseconds and the child-process runners."""

from __future__ import annotations

import json
import os
import platform
import resource
import subprocess
import sys

import numpy as np


def machine() -> dict:
    """What the figures were measured on: CPU architecture and model (:func:`cpu_model`), number
    of cores, Python and numpy versions. Hosts of one kind differ: the same code's figures on
    two models of CPU compare only through the baseline each run measures."""
    return {
        "cpu": platform.processor() or platform.machine(),
        "cpu_model": cpu_model(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
    }


def cpu_model(cpuinfo: str = "/proc/cpuinfo") -> str | None:
    """The CPU's model name as the kernel reports it (the first ``model name`` line of
    ``cpuinfo``, e.g. ``AMD EPYC``), None where there is none (not Linux, an unreadable file)."""
    try:
        with open(cpuinfo, encoding="utf-8", errors="replace") as f:
            for line in f:
                key, sep, value = line.partition(":")
                if sep and key.strip() == "model name":
                    return value.strip() or None
    except OSError:
        return None
    return None


def peak_rss_mb() -> float:
    """This process's peak resident memory so far, in MB (MiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def percentiles_ms(seconds: list[float]) -> tuple[float, float]:
    """Median and 99th percentile of durations given in s, both in ms."""
    a = np.asarray(seconds) * 1e3
    return float(np.median(a)), float(np.percentile(a, 99))


def latency_ms(seconds: list[float]) -> dict:
    """Latencies given in s: median, p95, p99 and maximum in ms, and their number."""
    a = np.asarray(seconds) * 1e3
    return {
        "median_ms": float(np.median(a)),
        "p95_ms": float(np.percentile(a, 95)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
        "requests": len(a),
    }


def child(name: str, *args: str) -> dict:
    """Run the child entry ``name(*args)`` (see :mod:`trainclimate.bench.__main__`) in a fresh
    Python process, ``python -m trainclimate.bench NAME ARGS…``; its JSON result (the last line
    it prints)."""
    out = subprocess.run(
        [sys.executable, "-m", "trainclimate.bench", name, *args],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def start_child(name: str, *args: str, stderr) -> subprocess.Popen:
    """Start the child entry ``name(*args)`` like :func:`child`, without waiting for it, so that
    several run at once: its stdin and stdout are pipes of text lines (for a child that takes
    turns with its parent), its stderr goes to the open file ``stderr``."""
    return subprocess.Popen(
        [sys.executable, "-m", "trainclimate.bench", name, *args],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=stderr,
        text=True,
        bufsize=1,
    )
