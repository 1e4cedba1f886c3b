"""LAZ chunks compressed in a worker process, for :class:`~mitsuforest.write.las.LasStream`.

lazrs holds Python's lock while it compresses, and its own threads make about three cores' worth of a
16-core machine's, so on many cores the writer hands blocks of whole chunks to worker processes. A LAZ
chunk is compressed on its own (its coder starts afresh), so blocks compressed apart and joined in order
are the bytes one compressor writes. This module imports only numpy and lazrs, so that a worker starts
without the package's heavy libraries.
"""

from __future__ import annotations

import io
import signal

import lazrs
import numpy as np


def ignore_interrupts() -> None:
    """A worker's initializer: Ctrl-C reaches the whole process group, and the parent, not each worker,
    answers it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def ready() -> bool:
    """A task that makes the pool start a worker (each worker takes one until all have started)."""
    import time
    time.sleep(0.05)
    return True


def compress_chunks(vlr_record: bytes, records: bytes) -> tuple[bytes, list[tuple[int, int]]]:
    """Point ``records`` (whole chunks of the LasZip VLR ``vlr_record``'s size, but for the file's last
    block) compressed: the chunks' bytes, and a (point count, byte count) chunk table entry for each."""
    vlr = lazrs.LazVlr(vlr_record)
    compressed = lazrs.compress_points(vlr, np.frombuffer(records, np.uint8), False)
    table = lazrs.read_chunk_table(io.BytesIO(compressed), vlr)   # after the 8-byte offset to the table
    return bytes(compressed[8:8 + sum(size for _, size in table)]), table
