"""Peak memory of a child process, as code for ``python -c``.

``ru_maxrss`` is the wrong measure there: Linux carries it across exec, so a child forked from a
1 GB pytest reports 1 GB before it does anything. ``VmHWM`` belongs to the new address space."""

PEAK_MB = "int(open('/proc/self/status').read().split('VmHWM:')[1].split()[0]) / 1024"
"""An expression for the calling process's peak resident memory in MB."""
