"""Run a command and say, at its end, how long it took: wall time, CPU time and the load average.

    python workflow/scripts/timed.py LABEL COMMAND [ARGUMENTS...]

The CPU time is that of every process the command started and waited for (the install's pip, Snakemake
and its jobs, their notebook kernels): ``getrusage(RUSAGE_CHILDREN)``, user plus system. The load average
(1 minute) before and after says how much else the machine ran meanwhile. The line goes to stderr; the
exit status is the command's. The standard library only (``make run`` calls it before the install).
"""
from __future__ import annotations

import os
import resource
import subprocess
import sys
import time


def duration(seconds: float) -> str:
    """``"9 min 12 s"`` (or ``"48.3 s"`` under a minute)."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, rest = divmod(round(seconds), 60)
    return f"{minutes} min {rest} s"


def main(label: str, command: list[str]) -> int:
    load_before = os.getloadavg()[0]
    began = time.monotonic()
    try:
        status = subprocess.call(command)
    except KeyboardInterrupt:
        status = 130
    wall = time.monotonic() - began
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = used.ru_utime + used.ru_stime
    outcome = "" if status == 0 else f" (it failed: exit status {status})"
    print(f"{label}: {duration(wall)} wall, {duration(cpu)} CPU in all its processes; load average "
          f"{load_before:.2f} before, {os.getloadavg()[0]:.2f} after{outcome}", file=sys.stderr, flush=True)
    return status


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    sys.exit(main(sys.argv[1], sys.argv[2:]))
