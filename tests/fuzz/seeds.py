#!/usr/bin/env python3
"""Seeds for the fuzz targets: small valid files of each format, made here,
and the small files of the shared data when it is present.

    python3 seeds.py CORPUS_DIR [SHARED_DATA_DIR]

Writes CORPUS_DIR/TARGET/NAME; existing files are kept (the corpus grows).
Each file-format target's input is its first byte (picking a variant, see the
target) followed by the file."""

import gzip
import os
import struct
import sys


def put(corpus, target, name, data):
    folder = os.path.join(corpus, target)
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, name), "wb") as f:
        f.write(data)


def volume(nx, ny, nz):
    return bytes((x * 7 + y * 3 + z * 11) % 251 for z in range(nz) for y in range(ny) for x in range(nx))


def nrrd_seeds(corpus):
    voxels = volume(8, 6, 5)
    head = b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 8 6 5\nspace: left-posterior-superior\n" \
           b"space directions: (1,0,0) (0,1.5,0) (0,0,2)\nspace origin: (0,0,0)\n"
    put(corpus, "nrrd", "raw", b"\x00" + head + b"encoding: raw\n\n" + voxels)
    put(corpus, "nrrd", "gzip", b"\x00" + head + b"encoding: gzip\n\n" + gzip.compress(voxels))
    put(corpus, "nrrd", "detached", b"\x01" + head.replace(b"NRRD0004", b"NRRD0005")
        + b"encoding: raw\nline skip: 1\nbyte skip: 2\ndata file: volume.raw\n\n#DATA#\nx\n" + b"ab" + voxels)
    put(corpus, "nrrd", "short-be", b"\x00" + head.replace(b"uint8", b"short")
        + b"endian: big\nencoding: raw\n\n" + voxels + voxels)


def nifti_header(nx, ny, nz, datatype, bitpix, slope=1.0, inter=0.0):
    h = bytearray(348)
    struct.pack_into("<i", h, 0, 348)
    struct.pack_into("<8h", h, 40, 3, nx, ny, nz, 1, 1, 1, 1)
    struct.pack_into("<hh", h, 70, datatype, bitpix)
    struct.pack_into("<8f", h, 76, 1.0, 1.0, 1.5, 2.0, 1, 1, 1, 1)
    struct.pack_into("<f", h, 108, 352.0)
    struct.pack_into("<ff", h, 112, slope, inter)
    struct.pack_into("<hh", h, 252, 1, 1)  # qform and sform codes
    struct.pack_into("<6f", h, 256, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    struct.pack_into("<4f", h, 280, 1, 0, 0, 0)
    struct.pack_into("<4f", h, 296, 0, 1.5, 0, 0)
    struct.pack_into("<4f", h, 312, 0, 0, 2, 0)
    h[344:348] = b"n+1\x00"
    return bytes(h) + b"\x00" * 4


def nifti_seeds(corpus):
    voxels = volume(8, 6, 5)
    put(corpus, "nifti", "u8", b"\x00" + nifti_header(8, 6, 5, 2, 8) + voxels)
    put(corpus, "nifti", "u8-gz", b"\x01" + gzip.compress(nifti_header(8, 6, 5, 2, 8) + voxels))
    put(corpus, "nifti", "i16-scaled", b"\x00" + nifti_header(8, 6, 5, 4, 16, 2.0, -1024.0) + voxels + voxels)
    floats = b"".join(struct.pack("<f", v / 3.0) for v in voxels)
    put(corpus, "nifti", "f32", b"\x00" + nifti_header(8, 6, 5, 16, 32) + floats)


def metaimage_seeds(corpus):
    voxels = volume(8, 6, 5)
    head = b"ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n" \
           b"TransformMatrix = 1 0 0 0 1 0 0 0 1\nOffset = 0 0 0\nElementSpacing = 1 1.5 2\n" \
           b"DimSize = 8 6 5\nElementType = MET_UCHAR\n"
    put(corpus, "metaimage", "local", b"\x00" + head + b"ElementDataFile = LOCAL\n" + voxels)
    put(corpus, "metaimage", "compressed", b"\x00" + head.replace(b"BinaryData = True\n",
        b"BinaryData = True\nCompressedData = True\n") + b"ElementDataFile = LOCAL\n"
        + __import__("zlib").compress(voxels))
    put(corpus, "metaimage", "detached", b"\x01" + head + b"HeaderSize = 2\nElementDataFile = volume.raw\n"
        + b"\n#DATA#\n" + b"xy" + voxels)


def text_seeds(corpus):
    for name in ["engine_256x256x128_uint8", "cthead_256x256x113_uint16be", "walnut_128x96x114_uint16le",
                 "scan_8x6x5_float32", "1,0,0,0,1,0,0,0,1", "x,y"]:
        put(corpus, "raw_names", name.replace(",", "_"), name.encode())
    for i, tf in enumerate(["-1000:#000000:0 300:#ffe0c0:0.2 1500:#ffffff:0.9", "0:#ff0000:0 1:#00ff00:1",
                            "-1024 0 0 0 0, 3071 1 1 1 1"]):
        put(corpus, "transfer_function", f"tf{i}", tf.encode())
    for i, q in enumerate(["az=30&el=10&w=64&h=48&preset=ct-bone",
                           "shading=extinction&lights=point:0,0,100:1;directional:0,1,0:0.5&reduction=8",
                           "mode=mip&clip=0.1,0.9,0,1,0,1&roll=30&fov=20&projection=orthographic",
                           "tf=-1000:%23000000:0%20300:%23ffffff:1&gamma=1.2"]):
        put(corpus, "view_query", f"q{i}", q.encode())
    for i, m in enumerate(['{"type":"view","id":1,"set":{"w":64,"h":48,"az":10}}',
                           '{"type":"ack","frame":3}', '{"type":"status","id":2}',
                           '{"type":"view","id":2,"set":{"preset":null,"lights":"point:0,0,100:1"},"dpr":2}']):
        put(corpus, "ws_message", f"m{i}", m.encode())
    root = b'{"zarr_format":3,"node_type":"group","attributes":{"voxserve":{"format_version":2,' \
           b'"complete":true,"name":"phantom","dims":[20,20,20],"voxel_type":"uint16","spacing":[1,1,1],' \
           b'"origin":[0,0,0],"direction":[[1,0,0],[0,1,0],[0,0,1]],"value_map":{"slope":1,"intercept":-1024},' \
           b'"unit":"HU","modality":"CT","description":null,"stored_range":[0,2000],"block_size":16,' \
           b'"levels":5,"histogram_bins":32,"blocks":[2,2,2],"source":"phantom","source_format":"raw",' \
           b'"notes":[]}}}'
    put(corpus, "store_metadata", "root", root)
    put(corpus, "dimse_command", "echo", dimse_command([
        (0x0002, b"1.2.840.10008.1.1\0"), (0x0100, struct.pack("<H", 0x0030)),
        (0x0110, struct.pack("<H", 1)), (0x0800, struct.pack("<H", 0x0101))]))
    put(corpus, "dimse_command", "store", dimse_command([
        (0x0002, b"1.2.840.10008.5.1.4.1.1.2\0"), (0x0100, struct.pack("<H", 0x0001)),
        (0x0110, struct.pack("<H", 7)), (0x0700, struct.pack("<H", 0)),
        (0x0800, struct.pack("<H", 0)), (0x1000, b"1.2.3.4")]))


def dimse_command(elements):
    """A command set: group 0000 elements (implicit VR little endian) after
    their group length."""
    body = b"".join(struct.pack("<HHI", 0, e, len(v)) + v for e, v in elements)
    return struct.pack("<HHII", 0, 0, 4, len(body)) + body


def shared_seeds(corpus, shared):
    if not shared or not os.path.isdir(shared):
        return
    nucleon = os.path.join(shared, "nrrd", "nucleon.nrrd")
    if os.path.isfile(nucleon):
        with open(nucleon, "rb") as f:
            head = f.read()
        with open(os.path.join(shared, "nrrd", "nucleon.raw"), "rb") as f:
            data = f.read()
        put(corpus, "nrrd", "nucleon", b"\x01" + head.replace(b"nucleon.raw", b"volume.raw") + b"\n#DATA#\n" + data)
    syntaxes = os.path.join(shared, "dicom", "transfer_syntaxes")
    if os.path.isdir(syntaxes):
        for name in sorted(os.listdir(syntaxes)):
            with open(os.path.join(syntaxes, name), "rb") as f:
                data = f.read()
            put(corpus, "dicom_file", name, data)
            put(corpus, "dicom_folder", name, data + b"#FILE#" + data)


def main():
    corpus = sys.argv[1]
    nrrd_seeds(corpus)
    nifti_seeds(corpus)
    metaimage_seeds(corpus)
    text_seeds(corpus)
    shared_seeds(corpus, sys.argv[2] if len(sys.argv) > 2 else None)


main()
