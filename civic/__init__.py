"""CIVIC: Continuous In-situ Validation of Industrial Control models."""
import os


def _pin_cpu_code_paths() -> None:
    """Rounding follows the CPU: numba compiles for the host and OpenBLAS picks its kernels by
    it, and `civic diagnose` keeps or drops its smallest findings on that rounding (the same
    Cascaded Tanks record gave five findings on an AVX2 machine, six on an AVX-512 one). On an
    x86 CPU with AVX2 and FMA both are pinned to their AVX2 (Haswell) code paths, so a result
    reproduces across such machines, as `constraints.txt` pins the versions. Takes effect only
    when civic is imported before numpy; a user's own setting wins."""
    try:
        with open("/proc/cpuinfo") as f:
            flags = next((line.split(":", 1)[1].split() for line in f if line.startswith("flags")), [])
    except OSError:
        return
    if {"avx2", "fma"} <= set(flags):
        os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")
        os.environ.setdefault("NUMBA_CPU_NAME", "haswell")


_pin_cpu_code_paths()

__version__ = "0.1.0"
