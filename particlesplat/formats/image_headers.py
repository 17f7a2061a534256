"""An image's size from its first bytes, before anything is decoded: what a reader reserves for its pixels
(:func:`particlesplat.core.limits.reserve_memory`) is known from the headers of all its images at once.

WebP (RIFF ``VP8L`` lossless, ``VP8X`` extended, ``VP8 `` lossy; the WebP container specification) and PNG
(``IHDR``) are read; :data:`HEAD_BYTES` of the file are enough for either.
"""

from __future__ import annotations

import struct

HEAD_BYTES = 32
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def image_header_size(head: bytes) -> tuple[int, int] | None:
    """(width, height) in pixels of the WebP or PNG image whose first bytes are ``head`` (at least
    :data:`HEAD_BYTES` of them, or the whole file); None when they are no header of either."""
    if head[:8] == PNG_SIGNATURE and len(head) >= 24 and head[12:16] == b"IHDR":
        width, height = struct.unpack(">II", head[16:24])
        return int(width), int(height)
    if len(head) < 30 or head[:4] != b"RIFF" or head[8:12] != b"WEBP":
        return None
    chunk = head[12:16]
    if chunk == b"VP8L" and head[20] == 0x2F:  # 14 bits of width - 1, 14 of height - 1
        bits = int.from_bytes(head[21:25], "little")
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if chunk == b"VP8X":  # the canvas: 24 bits of width - 1 and of height - 1
        return int.from_bytes(head[24:27], "little") + 1, int.from_bytes(head[27:30], "little") + 1
    if chunk == b"VP8 " and head[23:26] == b"\x9d\x01\x2a":  # a key frame's start code, then 14-bit sizes
        width, height = struct.unpack("<HH", head[26:30])
        return width & 0x3FFF, height & 0x3FFF
    return None
