#!/usr/bin/python3
"""Writes the seed corpora of fuzz_volume and fuzz_surface (tests/fuzz/corpus/{volume,surface}): small, valid files
in each format the readers take, each prefixed by the byte that selects the format in the fuzz target.
Standard library only. Usage: tests/fuzz/make_seeds.py"""
import gzip
import os
import struct
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
SIZE = (6, 5, 4)
LABELS = bytes((x + 2 * y + 3 * z) % 5 for z in range(SIZE[2]) for y in range(SIZE[1]) for x in range(SIZE[0]))


def write(kind, name, selector, data):
    directory = os.path.join(HERE, "corpus", kind)
    os.makedirs(directory, exist_ok=True)
    with open(os.path.join(directory, name), "wb") as f:
        f.write(bytes([selector]) + data)


def nifti(datatype=2, bitpix=8, data=LABELS, sform=True):
    header = bytearray(348)
    struct.pack_into("<i", header, 0, 348)
    struct.pack_into("<8h", header, 40, 3, *SIZE, 1, 1, 1, 1)
    struct.pack_into("<hh", header, 70, datatype, bitpix)
    struct.pack_into("<8f", header, 76, 1.0, 1.5, 1.5, 2.5, 1.0, 1.0, 1.0, 1.0)
    struct.pack_into("<f", header, 108, 352.0)  # vox_offset
    struct.pack_into("<f", header, 112, 1.0)    # scl_slope
    struct.pack_into("<b", header, 123, 10)     # xyzt_units: mm, s
    struct.pack_into("<hh", header, 252, 1, 1 if sform else 0)  # qform_code, sform_code
    struct.pack_into("<6f", header, 256, 0.0, 0.0, 0.0, -10.0, 20.0, -30.0)  # quatern b c d, qoffset
    struct.pack_into("<12f", header, 280, -1.5, 0, 0, 10.0, 0, -1.5, 0, -20.0, 0, 0, 2.5, -30.0)
    header[344:348] = b"n+1\0"
    return bytes(header) + b"\0\0\0\0" + data


def nrrd(encoding):
    payload = LABELS if encoding == "raw" else gzip.compress(LABELS)
    text = ("NRRD0004\ntype: uint8\ndimension: 3\nspace: left-posterior-superior\nsizes: %d %d %d\n"
            "space directions: (1.5,0,0) (0,1.5,0) (0,0,2.5)\nkinds: domain domain domain\nencoding: %s\n"
            "space origin: (10,20,-30)\n\n" % (*SIZE, encoding))
    return text.encode() + payload


def mha(compressed):
    payload = zlib.compress(LABELS) if compressed else LABELS
    text = ("ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
            "CompressedData = %s\n%sTransformMatrix = 1 0 0 0 1 0 0 0 1\nOffset = 10 20 -30\n"
            "ElementSpacing = 1.5 1.5 2.5\nDimSize = %d %d %d\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n"
            % ("True" if compressed else "False",
               ("CompressedDataSize = %d\n" % len(payload)) if compressed else "", *SIZE))
    return text.encode() + payload


write("volume", "labels_uint8.nii", 0, nifti())
write("volume", "ct_int16_qform.nii", 0,
      nifti(4, 16, b"".join(struct.pack("<h", v * 100 - 200) for v in LABELS), sform=False))
write("volume", "labels.nii.gz", 1, gzip.compress(nifti()))
write("volume", "labels_raw.nrrd", 2, nrrd("raw"))
write("volume", "labels_gzip.nrrd", 2, nrrd("gzip"))
write("volume", "labels.mha", 3, mha(False))
write("volume", "labels_compressed.mha", 3, mha(True))

# A tetrahedron in each surface format.
V = [(0, 0, 0), (10, 0, 0), (0, 10, 0), (0, 0, 10)]
F = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]


def normal(f):
    a, b, c = (V[i] for i in f)
    u = [b[k] - a[k] for k in range(3)]
    w = [c[k] - a[k] for k in range(3)]
    return (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])


obj = "# tetrahedron\n" + "".join("v %g %g %g\n" % v for v in V) + "".join(
    "f %d %d %d\n" % tuple(i + 1 for i in f) for f in F)
write("surface", "tetra.obj", 0, obj.encode())
write("surface", "tetra_quads_and_negatives.obj", 0,
      ("v 0 0 0\nv 10 0 0\nv 10 10 0\nv 0 10 0\nvn 0 0 1\nf -4//1 -3//1 -2//1 -1//1\n").encode())
ply_head = "ply\nformat %s 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n" \
           "element face 4\nproperty list uchar int vertex_indices\nend_header\n"
write("surface", "tetra_ascii.ply", 1, (ply_head % "ascii" + "".join("%g %g %g\n" % v for v in V) +
                                        "".join("3 %d %d %d\n" % f for f in F)).encode())
write("surface", "tetra_binary.ply", 1, (ply_head % "binary_little_endian").encode() +
      b"".join(struct.pack("<3f", *v) for v in V) + b"".join(struct.pack("<B3i", 3, *f) for f in F))
stl = "solid tetra\n" + "".join(
    "facet normal %g %g %g\nouter loop\n%sendloop\nendfacet\n" % (*normal(f), "".join(
        "vertex %g %g %g\n" % V[i] for i in f)) for f in F) + "endsolid tetra\n"
write("surface", "tetra_ascii.stl", 2, stl.encode())
write("surface", "tetra_binary.stl", 2, b"\0" * 80 + struct.pack("<I", len(F)) + b"".join(
    struct.pack("<12fH", *normal(f), *V[f[0]], *V[f[1]], *V[f[2]], 0) for f in F))
vtp = ('<?xml version="1.0"?>\n<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian">\n<PolyData>\n'
       '<Piece NumberOfPoints="4" NumberOfVerts="0" NumberOfLines="0" NumberOfStrips="0" NumberOfPolys="4">\n'
       '<Points><DataArray type="Float32" NumberOfComponents="3" format="ascii">%s</DataArray></Points>\n'
       '<Polys><DataArray type="Int32" Name="connectivity" format="ascii">%s</DataArray>\n'
       '<DataArray type="Int32" Name="offsets" format="ascii">3 6 9 12</DataArray></Polys>\n'
       '</Piece>\n</PolyData>\n</VTKFile>\n') % (" ".join("%g %g %g" % v for v in V),
                                                  " ".join("%d %d %d" % f for f in F))
write("surface", "tetra.vtp", 3, vtp.encode())
