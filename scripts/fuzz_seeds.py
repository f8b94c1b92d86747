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
HEADER_DIR = ROOT / "shared/ipc/tests/__fuzz__/frame_header/corpus"
GRID_DIR = ROOT / "tests/__fuzz__/grid_message/corpus"


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


def header(kind, frame_id, status=0, stage=0, count=0, size=(8, 6), dims=(64, 64, 64),
           version=2, message=b"") -> bytes:
    """A FrameHeader's little-endian #[repr(C)] bytes (shared/ipc/src/header.rs)."""
    stamps = [1_700_000_000_000_000_000 + 1000 * i for i in range(8)]
    out = struct.pack("<IIQIIII", version, kind, frame_id, 0, status, stage, count)
    out += struct.pack("<8Q", *stamps)
    out += struct.pack("<2I", *size)
    out += struct.pack("<4f", 7.25, 7.25, 3.5, 2.5)
    out += struct.pack("<7f", 0.288, 0.288, 0.9, 1.0, 0.0, 0.0, 0.0)
    out += struct.pack("<3I", *dims) + struct.pack("<2f", 0.009, 0.036)
    out += struct.pack("<4HI", 0, 0, 0, 0, 4242)
    out += message.ljust(164, b"\0")[:164]
    assert len(out) == 344
    return out


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

    HEADER_DIR.mkdir(parents=True, exist_ok=True)
    seeds = {
        # A depth frame header followed by its payload (8×6 f32 metres).
        "depth-frame.bin": header(1, 7, count=48) + struct.pack("<48f", *([0.7] * 48)),
        # A grid header followed by a 2³-voxel grid (3·8 normals, 8 TSDF values).
        "grid.bin": header(2, 8, count=32, dims=(2, 2, 2)) + struct.pack("<32f", *([0.5] * 32)),
        "error-record.bin": header(3, 9, status=3, stage=2, message="no surface in the workspace".encode()),
        "unknown-status.bin": header(4, 10, status=99, stage=77, message="é".encode() * 100),
        "old-version.bin": header(1, 11, version=0),
        "grid-too-large.bin": header(2, 12, dims=(4096, 4096, 4096)),
    }
    for name, data in seeds.items():
        (HEADER_DIR / name).write_bytes(data)
    # The inference stage's view of a grid message: the same headers with their payloads.
    GRID_DIR.mkdir(parents=True, exist_ok=True)
    for name in ["grid.bin", "depth-frame.bin", "grid-too-large.bin"]:
        (GRID_DIR / name).write_bytes(seeds[name])
    normals = [0.0, 0.0, 1.0] * 8
    tsdf = [1.0, 0.5, -0.5, -1.0, 1.5, float("nan"), 0.0, 0.2]
    (GRID_DIR / "grid-bad-tsdf.bin").write_bytes(
        header(2, 13, count=32, dims=(2, 2, 2)) + struct.pack("<32f", *(normals[0::3] * 3 + tsdf))
    )


if __name__ == "__main__":
    main()
