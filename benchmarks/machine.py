"""What the benchmarks print about the machine they ran on."""

from __future__ import annotations

import os


def cpu_description() -> str:
    """CPU model and core count, from /proc/cpuinfo where there is one."""
    try:
        with open("/proc/cpuinfo") as fh:
            name = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        name = "unknown CPU"
    return f"{name}, {os.cpu_count()} cores"
