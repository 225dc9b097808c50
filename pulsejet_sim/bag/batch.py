"""
A batch of CDR messages for BagWriter.write_batch: blocks of one topic each, merged by order key.

The offline runner collects a stretch of its run as columns, encodes each topic's messages at once
(bag.cdr.ColumnEncoder) and hands them over as one batch. Each message carries an integer order
key (the runner's publication and slot), so the batch is written in the order sim_node publishes,
the same file as one write_records call per publication.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class Block:
    """
    The messages of one topic: keys, log times and bytes.

    rows: an (n, size) uint8 array of equal-size messages, or a sequence of n bytes objects.
    """

    topic: str
    keys: np.ndarray
    log_ns: np.ndarray
    rows: np.ndarray | Sequence[bytes]

    @property
    def sizes(self) -> np.ndarray:
        if isinstance(self.rows, np.ndarray):
            return np.full(len(self.keys), self.rows.shape[1], dtype=np.int64)
        return np.array([len(r) for r in self.rows], dtype=np.int64)


@dataclass
class RecordBatch:
    """Blocks of messages; merged() puts them in order of their keys (ties: block order)."""

    blocks: list[Block] = field(default_factory=list)

    def add(self, topic: str, keys, log_ns, rows) -> None:
        """Add the messages of one topic; keys and log_ns: one integer each (ns for log_ns)."""
        keys = np.asarray(keys, dtype=np.int64).reshape(-1)
        log_ns = np.asarray(log_ns, dtype=np.int64).reshape(-1)
        count = len(rows)
        if not (len(keys) == len(log_ns) == count):
            raise ValueError(
                f'topic {topic!r}: {len(keys)} keys, {len(log_ns)} log times and {count} '
                'messages; allowed: one key and one log time per message'
            )
        if isinstance(rows, np.ndarray) and (rows.ndim != 2 or rows.dtype != np.uint8):
            raise ValueError(
                f'topic {topic!r}: rows of shape {rows.shape} and type {rows.dtype}; allowed: '
                'an (n, size) uint8 array or a list of bytes'
            )
        if count:
            self.blocks.append(Block(topic, keys, log_ns, rows))

    def merged(self) -> 'Merged':
        """Return the batch in write order."""
        if not self.blocks:
            empty = np.zeros(0, dtype=np.int64)
            return Merged(self.blocks, empty, empty, empty, empty)
        order = np.argsort(np.concatenate([b.keys for b in self.blocks]), kind='stable')
        block_of = np.repeat(np.arange(len(self.blocks)), [len(b.keys) for b in self.blocks])
        row_of = np.concatenate([np.arange(len(b.keys)) for b in self.blocks])
        return Merged(
            blocks=self.blocks,
            block_of=block_of[order],
            row_of=row_of[order],
            log_ns=np.concatenate([b.log_ns for b in self.blocks])[order],
            sizes=np.concatenate([b.sizes for b in self.blocks])[order],
        )


@dataclass(frozen=True)
class Merged:
    """A batch in write order: record i is row row_of[i] of blocks[block_of[i]]."""

    blocks: list[Block]
    block_of: np.ndarray
    row_of: np.ndarray
    log_ns: np.ndarray
    sizes: np.ndarray

    def scatter(self, out: np.ndarray, starts: np.ndarray, heads: np.ndarray, part: slice) -> None:
        """
        Write records part (head then message bytes) into out at byte offsets starts.

        heads: (len(part), head size) uint8, the record heads of those records. Small messages
        are placed by one fancy-indexed copy per topic (its cost goes with the bytes), large ones
        (a mantle profile) by a slice copy each (its cost goes with the count).
        """
        block_of = self.block_of[part]
        row_of = self.row_of[part]
        width = heads.shape[1]
        out[starts[:, None] + np.arange(width)] = heads
        for b in np.unique(block_of):
            block = self.blocks[b]
            sel = np.flatnonzero(block_of == b)
            at = starts[sel] + width
            if isinstance(block.rows, np.ndarray) and block.rows.shape[1] < _SLICE_BYTES:
                out[at[:, None] + np.arange(block.rows.shape[1])] = block.rows[row_of[sel]]
                continue
            view = memoryview(out)
            rows = block.rows
            for i, row in zip(at.tolist(), row_of[sel].tolist()):
                data = rows[row]
                view[i:i + len(data)] = data


#: messages from this size on are copied one slice each (measured break-even about 160 bytes)
_SLICE_BYTES = 160
