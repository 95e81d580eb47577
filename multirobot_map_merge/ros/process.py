"""Process-wide settings of the node: malloc arenas (flat memory) and a hard exit soon after shutdown."""
from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import threading

HARD_EXIT = 1.6         # s (wall) after a shutdown request the process ends even if rospy's shutdown still runs


def limit_malloc_arenas() -> None:
    """glibc gives each thread (rospy runs one per connection) its own malloc arena, and after a large block is
    freed it serves blocks up to that size from the arenas instead of mmap: freed numpy arrays of a long run then
    stay resident. Two arenas and a fixed 128 KiB mmap threshold keep RSS flat (without them a node with 30
    live robots holds over twice the memory within minutes). No-op where libc has no mallopt."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library('c') or 'libc.so.6')
        m_trim_threshold, m_mmap_threshold, m_arena_max = -1, -3, -8   # glibc's malloc.h
        libc.mallopt(m_arena_max, 2)
        libc.mallopt(m_mmap_threshold, 128 * 1024)
        libc.mallopt(m_trim_threshold, 128 * 1024)
    except (OSError, AttributeError):
        pass


def exit_now() -> None:
    logging.shutdown()   # flush the log files
    os._exit(0)


def start_exit_watchdog() -> None:
    """rospy's shutdown unregisters every topic from the master and joins its threads (up to 5 s each): with many
    robots on a loaded machine that alone can approach 2 s. The issue wants the node gone within 2 s of SIGINT."""
    timer = threading.Timer(HARD_EXIT, exit_now)
    timer.daemon = True
    timer.start()
