"""The C heap of a run in parts: freed pages handed back, large blocks in their own mappings
(glibc; elsewhere nothing), so that the resident size of a long file's run stays that of a part."""

from __future__ import annotations

__all__ = ["map_large_blocks", "release_memory"]


def release_memory() -> None:
    """Hand the heap's free pages back to the system (glibc ``malloc_trim``; elsewhere nothing).

    The parts' arrays are freed when a part is done, but the C heap keeps the pages of freed
    blocks below its top, so the resident size would creep up part after part."""
    global _TRIM
    if _TRIM is None:
        try:
            import ctypes

            _TRIM = ctypes.CDLL("libc.so.6").malloc_trim
        except (OSError, AttributeError):
            _TRIM = False
    if _TRIM:
        _TRIM(0)


_TRIM = None
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
