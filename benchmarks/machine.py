"""What machine a benchmark ran on (recorded in every benchmark's JSON)."""

from __future__ import annotations

import os
import platform

import numpy as np


def machine_info() -> dict:
    info = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
    }
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    info["cpu_model"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        with open("/proc/meminfo") as f:
            info["memory_kb"] = int(f.readline().split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return info


def machine_line(info: dict) -> str:
    """The first line of a benchmark's table: which machine (from :func:`machine_info`)."""
    return (f"machine: {info.get('cpu_model', '?')}, {info['cpu_count']} cores, numpy {info['numpy']}, "
            f"python {info['python']}")
