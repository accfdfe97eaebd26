"""A PNG writer with its own deflate: zlib's output may change between versions, and the asset must not."""

from __future__ import annotations

import struct
import zlib

import numpy as np

# -- images -----------------------------------------------------------------------------------------------------


def png_bytes(image: np.ndarray) -> bytes:
    """A PNG of an (H, W, 3 or 4) uint8 image, every row Paeth-filtered, compressed by `deflate` here rather than
    by zlib: a zlib's output may change between versions (zlib, zlib-ng), this cannot, so the bytes depend on
    the pixels alone."""
    height, width, channels = image.shape
    colour_type = {3: 2, 4: 6}[channels]
    x = image.astype(np.int16)
    left = np.zeros_like(x)
    left[:, 1:] = x[:, :-1]
    up = np.zeros_like(x)
    up[1:] = x[:-1]
    up_left = np.zeros_like(x)
    up_left[1:, 1:] = x[:-1, :-1]
    estimate = left + up - up_left
    pa, pb, pc = np.abs(estimate - left), np.abs(estimate - up), np.abs(estimate - up_left)
    predictor = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, up_left))
    filtered = ((x - predictor) % 256).astype(np.uint8).reshape(height, width * channels)
    raw = np.concatenate([np.full((height, 1), 4, np.uint8), filtered], axis=1).tobytes()
    stream = b"\x78\x01" + deflate(raw) + struct.pack(">I", zlib.adler32(raw))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", stream) + chunk(b"IEND", b"")


# deflate's length codes 257..285: (first length, extra bits) (RFC 1951, 3.2.5)
_LENGTH_BASE = (3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115, 131, 163,
                195, 227, 258)
_LENGTH_EXTRA = (0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0)
_CODE_LENGTH_ORDER = (16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15)


def _huffman_lengths(frequencies: np.ndarray, limit: int) -> np.ndarray:
    """Code lengths of a Huffman code for `frequencies` (0: unused), none longer than `limit`: ties broken by
    symbol, and where the tree grows too deep the counts are flattened and the code made again."""
    import heapq

    counts = frequencies.astype(np.int64)
    while True:
        used = [int(s) for s in np.nonzero(counts)[0]]
        lengths = np.zeros(len(counts), dtype=np.int64)
        if len(used) == 1:
            lengths[used[0]] = 1
            return lengths
        heap = [(int(counts[s]), s, (s,)) for s in used]
        heapq.heapify(heap)
        while len(heap) > 1:
            w1, k1, s1 = heapq.heappop(heap)
            w2, k2, s2 = heapq.heappop(heap)
            for s in s1 + s2:
                lengths[s] += 1
            heapq.heappush(heap, (w1 + w2, min(k1, k2), s1 + s2))
        if lengths.max() <= limit:
            return lengths
        counts = np.where(counts > 0, (counts + 1) // 2, 0)


def _canonical_codes(lengths: np.ndarray) -> np.ndarray:
    """Deflate's canonical codes for code lengths, bit-reversed, as the LSB-first stream carries them."""
    codes = np.zeros(len(lengths), dtype=np.int64)
    code = 0
    for length in range(1, int(lengths.max()) + 1):
        for symbol in np.nonzero(lengths == length)[0]:
            codes[symbol] = int(f"{code:0{length}b}"[::-1], 2)
            code += 1
        code <<= 1
    return codes


def deflate(data: bytes) -> bytes:
    """A raw deflate stream (RFC 1951) of one block with dynamic Huffman codes: literals, and runs of a repeated
    byte as matches at distance 1. Plain and slow next to zlib, but its output is fixed by this code alone."""
    raw = np.frombuffer(data, dtype=np.uint8)
    n = len(raw)
    # a run of k equal bytes: one literal, then matches of up to 258 (the last at least 3), the rest literals
    match_len = np.zeros(n, dtype=np.int64)
    covered = np.zeros(n, dtype=bool)
    change = np.nonzero(np.diff(raw.astype(np.int16)) != 0)[0] + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [n]])
    for s, e in zip(starts[ends - starts >= 4], ends[ends - starts >= 4], strict=True):
        pos, left = int(s) + 1, int(e - s) - 1
        while left >= 3:
            take = min(left, 258)
            if 0 < left - take < 3:
                take = left - 3 if left - 3 >= 3 else take
            match_len[pos] = take
            covered[pos + 1:pos + take] = True
            pos += take
            left -= take
    emit = np.nonzero(~covered)[0]
    lengths_here = match_len[emit]
    is_match = lengths_here > 0
    length_code = np.searchsorted(np.array(_LENGTH_BASE), lengths_here, side="right") - 1
    symbols = np.where(is_match, 257 + length_code, raw[emit].astype(np.int64))
    frequencies = np.bincount(np.concatenate([symbols, [256]]), minlength=286)
    lit_lengths = _huffman_lengths(frequencies, 15)
    lit_codes = _canonical_codes(lit_lengths)
    dist_lengths = np.array([1])  # one distance code: 0, distance 1

    cl_symbols = np.concatenate([lit_lengths, dist_lengths])  # code lengths sent as plain symbols 0..15
    cl_lengths = _huffman_lengths(np.bincount(np.concatenate([cl_symbols, [0, 1]]), minlength=19), 7)
    cl_codes = _canonical_codes(cl_lengths)

    values: list[np.ndarray] = []
    widths: list[np.ndarray] = []

    def put(value: np.ndarray | list[int], width: np.ndarray | list[int]) -> None:
        values.append(np.asarray(value, dtype=np.int64))
        widths.append(np.asarray(width, dtype=np.int64))

    put([1, 2, 286 - 257, 0, 19 - 4], [1, 2, 5, 5, 4])  # last block, dynamic codes, HLIT, HDIST, HCLEN
    put([int(cl_lengths[s]) for s in _CODE_LENGTH_ORDER], [3] * 19)
    put(cl_codes[cl_symbols], cl_lengths[cl_symbols])
    base = np.array(_LENGTH_BASE)[np.clip(length_code, 0, 28)]
    extra_width = np.where(is_match, np.array(_LENGTH_EXTRA)[np.clip(length_code, 0, 28)], 0)
    token_values = np.stack([lit_codes[symbols], np.where(is_match, lengths_here - base, 0),
                             np.zeros(len(symbols), dtype=np.int64)], axis=1)
    token_widths = np.stack([lit_lengths[symbols], extra_width, np.where(is_match, 1, 0)], axis=1)
    put(token_values.reshape(-1), token_widths.reshape(-1))  # symbol, its extra bits, the distance code (0)
    put([int(lit_codes[256])], [int(lit_lengths[256])])
    value = np.concatenate(values)
    width = np.concatenate(widths)
    keep = width > 0
    value, width = value[keep], width[keep]
    start = np.cumsum(width) - width
    item = np.repeat(np.arange(len(width)), width)
    bit = (value[item] >> (np.arange(int(width.sum())) - start[item])) & 1
    return np.packbits(bit.astype(np.uint8), bitorder="little").tobytes()
