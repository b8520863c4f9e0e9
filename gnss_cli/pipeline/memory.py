"""The C heap of a run in parts: large blocks in their own mappings (glibc; elsewhere nothing),
so that the resident size of a long file's run stays that of a part."""

from __future__ import annotations

__all__ = ["map_large_blocks"]

_M_MMAP_THRESHOLD = -3  # glibc mallopt parameter


def map_large_blocks() -> None:
    """Have glibc serve blocks of 256 KiB and more from their own mappings, returned to the
    system when freed, for the rest of the process (elsewhere than glibc: nothing). Its default
    threshold rises with the largest block freed, up to 32 MiB; the parts' arrays then come
    from the heap, whose freed pages stay resident and fragment, and the peak creeps up part
    after part. Set only when a file is run in parts: the mappings cost page faults (a whole
    24 h 30 s file ran 25 % slower with it)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").mallopt(_M_MMAP_THRESHOLD, 256 * 1024)
    except (OSError, AttributeError):
        pass
