#!/usr/bin/env python3
"""Writes the binary seed corpora of the fuzz targets (docs/testing.md, "Fuzzing"): tiny depth
PNGs and .npy files, valid and broken. The text seeds (configs, cards, intrinsics) are copies
or cut-down versions of the repository's own files and are committed as they are.

    python3 scripts/fuzz_seeds.py   # from the repository root; rewrites the files below
"""
import struct
import zlib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PNG_DIR = ROOT / "shared/fusion/tests/__fuzz__/depth_png/corpus"
NPY_DIR = ROOT / "tests/__fuzz__/depth_npy/corpus"


def chunk(kind: bytes, data: bytes, crc=None) -> bytes:
    crc = zlib.crc32(kind + data) if crc is None else crc
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)


def png(width, height, bit_depth, color, rows: bytes, ihdr_extra=b"\0\0\0", crc=None) -> bytes:
    ihdr = struct.pack(">IIBB", width, height, bit_depth, color) + ihdr_extra
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(rows), crc)
        + chunk(b"IEND", b"")
    )


def gray16_rows(width, height, value) -> bytes:
    out = b""
    for v in range(height):
        out += b"\0" + b"".join(struct.pack(">H", value(u, v)) for u in range(width))
    return out


def npy(descr: str, shape: str, body: bytes, version=1, fortran="False") -> bytes:
    header = "{'descr': '%s', 'fortran_order': %s, 'shape': %s, }" % (descr, fortran, shape)
    header += " " * ((64 - (10 + len(header) + 1) % 64) % 64) + "\n"
    if version == 1:
        return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode()
    return b"\x93NUMPY" + bytes([version, 0]) + struct.pack("<I", len(header)) + header.encode() + body


def main():
    PNG_DIR.mkdir(parents=True, exist_ok=True)
    ramp = gray16_rows(8, 6, lambda u, v: 600 + 10 * u + 100 * v)
    valid = png(8, 6, 16, 0, ramp)
    seeds = {
        "valid-8x6-mm.png": valid,
        "valid-8x6-holes.png": png(8, 6, 16, 0, gray16_rows(8, 6, lambda u, v: 0 if (u + v) % 3 else 750)),
        "valid-1x1.png": png(1, 1, 16, 0, b"\0\x02\xee"),
        "gray8-8x6.png": png(8, 6, 8, 0, b"".join(b"\0" + bytes(range(8)) for _ in range(6))),
        "rgb16-2x2.png": png(2, 2, 16, 2, (b"\0" + b"\x01\x00" * 6) * 2),
        "truncated-idat.png": valid[: len(valid) - 30],
        "bad-crc.png": png(8, 6, 16, 0, ramp, crc=0),
        # The header of an 8192² frame (530 MB once decoded) in front of a few bytes of data:
        # refused from the header, before any buffer exists.
        "header-8192x8192.png": png(8192, 8192, 16, 0, b"\0" * 64),
        "header-8x6-short-data.png": png(8, 6, 16, 0, ramp[:20]),
        "not-a-png.png": b"not a png",
    }
    for name, data in seeds.items():
        (PNG_DIR / name).write_bytes(data)

    NPY_DIR.mkdir(parents=True, exist_ok=True)
    u2 = b"".join(struct.pack("<H", 600 + i) for i in range(48))
    f4 = b"".join(struct.pack("<f", 0.6 + 0.001 * i) for i in range(48))
    f8 = b"".join(struct.pack("<d", 0.6 + 0.001 * i) for i in range(48))
    seeds = {
        "u2-6x8.npy": npy("<u2", "(6, 8)", u2) + u2,
        "f4-6x8.npy": npy("<f4", "(6, 8)", f4) + f4,
        "f8-6x8.npy": npy("<f8", "(6, 8)", f8) + f8,
        "f4-6x8-v2.npy": npy("<f4", "(6, 8)", f4, version=2),
        "f4-short.npy": npy("<f4", "(6, 8)", f4) + f4[:40],
        "f4-fortran.npy": npy("<f4", "(6, 8)", f4, fortran="True") + f4,
        "f4-3d.npy": npy("<f4", "(2, 3, 8)", f4) + f4,
        "i4-6x8.npy": npy("<i4", "(6, 8)", f4) + f4,
        # Shapes whose pixel count wraps in 64 bits, and an 8192² frame: refused from the header.
        "f4-huge-shape.npy": npy("<f4", "(4294967296, 4294967297)", f4) + f4,
        "f4-8192x8192.npy": npy("<f4", "(8192, 8192)", f4) + f4,
        "not-npy.npy": b"hello",
    }
    for name, data in seeds.items():
        (NPY_DIR / name).write_bytes(data)


if __name__ == "__main__":
    main()
