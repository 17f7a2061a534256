"""What machine this is, as benchmarks and the measured rasterizer choice name it: the CPU's model (no torch)."""

from __future__ import annotations

import platform


def cpu_model() -> str:
    """The CPU's model name as ``lscpu`` shows it (``/proc/cpuinfo``'s "model name"; elsewhere the platform's
    processor string), e.g. "AMD EPYC" or "INTEL(R) XEON(R) PLATINUM 8581C"; "unknown CPU" when neither says."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip() or "unknown CPU"
    except OSError:
        pass
    return platform.processor() or "unknown CPU"
