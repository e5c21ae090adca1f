"""The process's C heap (glibc): one heap for all threads, and freed pages given back; nothing elsewhere.

``one_heap`` is a process-wide allocator setting, so the process's entry point (``benchtwin.cli.main``) makes it,
not the library functions a caller may import into a process of its own.
"""

from __future__ import annotations

#: glibc's ``mallopt`` parameter for the most heaps ("arenas") the threads of the process spread over
_M_ARENA_MAX = -8


def one_heap() -> None:
    """Let the threads started from now on allocate from the main C heap (glibc's ``M_ARENA_MAX`` = 1).

    A thread's own heap keeps its free top resident (up to glibc's trim threshold, which grows to 64 MB with the
    arrays freed) and ``malloc_trim`` trims only the main heap's top, so :func:`give_back_freed_memory` left the
    free tops of the plant's, the encoder's and the type B re-runs' threads resident: a floor under every later
    stage of ``validate`` that rose with the campaign (RssAnon at the chain checks' start 274 MB at paper x1,
    332 MB at x3, with the same bytes in use). Does nothing where the C library is not glibc.
    """
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").mallopt(_M_ARENA_MAX, 1)
    except (OSError, AttributeError):  # not glibc
        return


def give_back_freed_memory() -> None:
    """Return the C heap's freed pages to the system (glibc's ``malloc_trim``; nothing elsewhere).

    The chain frees many mid-sized arrays that glibc keeps for reuse instead of unmapping: measured on the paper
    campaign, 250 MB of the resident set after the chain are free heap that the next stage does not reuse.
    """
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        return
