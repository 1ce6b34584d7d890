#!/usr/bin/env python3
"""Reads a pose that posewarp wrote as DICOM with readers that are not posewarp's and checks every voxel against the
NIfTI volumes of the same pose: highdicom (the CT, a series or one Enhanced CT, and the SEG, binary or label map),
dcmqi's segimage2itkimage (the SEG, merged into one label volume) and SimpleITK (the CT).

Usage: read_independently.py DICOM_DIR LABELS.nii.gz CT.nii.gz
DICOM_DIR holds ct/ (the CT's files) and seg.dcm, as `posewarp pose --dicom-out` writes them. Prints one line per
reader; exits 1 when a reader fails or sees other voxels than the NIfTI volumes hold.
"""
import glob
import logging
import os
import subprocess
import sys
import tempfile

import highdicom as hd
import nibabel as nib
import numpy as np
import pydicom
import SimpleITK as sitk

# highdicom warns that an Enhanced CT names its source images twice: in the Common Instance Reference module and as
# its Source Image Evidence, which the Enhanced CT IOD asks for both (dciodvfy checks it).
logging.getLogger("highdicom").setLevel(logging.ERROR)

RAS_TO_LPS = np.diag([-1.0, -1.0, 1.0, 1.0])
LABEL_MAP_SEG = "1.2.840.10008.5.1.4.1.1.66.7"


def on_reference(array, affine, reference, reference_affine):
    """The reference's values at the places of `array`'s voxels (every voxel must sit on a reference voxel)."""
    index = np.indices(array.shape).reshape(3, -1)
    homogeneous = np.vstack([index, np.ones((1, index.shape[1]))])
    at = (np.linalg.inv(reference_affine) @ affine @ homogeneous)[:3]
    nearest = np.rint(at)
    if np.abs(at - nearest).max() > 1e-3:
        raise AssertionError("its voxels do not sit on the NIfTI volume's voxels (%.4f voxel off)"
                             % np.abs(at - nearest).max())
    nearest = nearest.astype(np.int64)
    if (nearest < 0).any() or (nearest.T >= np.array(reference.shape)).any():
        raise AssertionError("its grid reaches outside the NIfTI volume's")
    return reference[tuple(nearest)].reshape(array.shape)


def check(name, array, affine, reference, reference_affine):
    expected = on_reference(array, affine, reference, reference_affine)
    wrong = int(np.count_nonzero(array != expected))
    if array.size != reference.size:
        raise AssertionError("%s: %d voxels, the NIfTI volume %d" % (name, array.size, reference.size))
    if wrong:
        raise AssertionError("%s: %d of %d voxels differ from the NIfTI volume" % (name, wrong, array.size))
    print("%s: %d voxels, all as in the NIfTI volume" % (name, array.size))


def numbers_to_labels(seg_numbers, labels, label_map):
    """Each segment number's label value: a label map's numbers are the labels; a binary SEG numbers the labels
    present 1, 2, 3, ... in value order."""
    present = [int(v) for v in np.unique(labels) if v != 0]
    if len(seg_numbers) != len(present):
        raise AssertionError("%d segments for %d labels" % (len(seg_numbers), len(present)))
    if label_map:
        if sorted(seg_numbers) != present:
            raise AssertionError("the label map's segment numbers are not the labels present")
        return {n: n for n in seg_numbers}
    return {n: present[n - 1] for n in seg_numbers}


def relabelled(array, mapping):
    out = np.zeros(array.shape, dtype=np.int64)
    for number, label in mapping.items():
        out[array == number] = label
    return out


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    dicom_dir, labels_path, ct_path = sys.argv[1:]
    labels_image, ct_image = nib.load(labels_path), nib.load(ct_path)
    labels = np.asarray(labels_image.dataobj).astype(np.int64)
    ct = np.asarray(ct_image.dataobj).astype(np.float64)
    labels_affine = RAS_TO_LPS @ labels_image.affine
    ct_affine = RAS_TO_LPS @ ct_image.affine
    seg_path = os.path.join(dicom_dir, "seg.dcm")
    ct_files = sorted(glob.glob(os.path.join(dicom_dir, "ct", "*.dcm")))

    # The SEG, through highdicom: its segments combined into one volume of segment numbers.
    seg = hd.seg.segread(seg_path)
    label_map = seg.SOPClassUID == LABEL_MAP_SEG
    mapping = numbers_to_labels(list(seg.segment_numbers), labels, label_map)
    volume = seg.get_volume(combine_segments=True, relabel=False)
    check("highdicom, %s SEG" % ("label map" if label_map else "binary"),
          relabelled(np.asarray(volume.array), mapping), volume.affine, labels, labels_affine)

    # The SEG, through dcmqi (DCMTK's dcmseg): one merged label volume written as NIfTI.
    with tempfile.TemporaryDirectory() as out:
        run = subprocess.run(["segimage2itkimage", "--inputDICOM", seg_path, "--outputDirectory", out, "-t", "nii",
                              "--mergeSegments"], capture_output=True, text=True)
        if run.returncode != 0:
            raise AssertionError("dcmqi's segimage2itkimage failed:\n" + run.stdout[-2000:] + run.stderr[-2000:])
        merged = nib.load(os.path.join(out, "1.nii.gz"))
        check("dcmqi segimage2itkimage, %s SEG" % ("label map" if label_map else "binary"),
              relabelled(np.asarray(merged.dataobj).astype(np.int64), mapping), RAS_TO_LPS @ merged.affine, labels,
              labels_affine)

    # The CT, through highdicom: one Enhanced CT image, or a series.
    if len(ct_files) == 1:
        ct_volume = hd.imread(ct_files[0]).get_volume()
        kind = "Enhanced CT"
    else:
        ct_volume = hd.get_volume_from_series([pydicom.dcmread(f) for f in ct_files])
        kind = "CT series of %d images" % len(ct_files)
    check("highdicom, " + kind, np.asarray(ct_volume.array), ct_volume.affine, ct, ct_affine)

    # The CT, through SimpleITK (GDCM), as its users read DICOM.
    if len(ct_files) == 1:
        image = sitk.ReadImage(ct_files[0])
    else:
        reader = sitk.ImageSeriesReader()
        reader.SetFileNames(list(sitk.ImageSeriesReader.GetGDCMSeriesFileNames(os.path.join(dicom_dir, "ct"))))
        image = reader.Execute()
    affine = np.eye(4)
    affine[:3, :3] = np.array(image.GetDirection()).reshape(3, 3) @ np.diag(image.GetSpacing())
    affine[:3, 3] = image.GetOrigin()
    # GetArrayFromImage orders the axes z, y, x.
    check("SimpleITK, " + kind, sitk.GetArrayFromImage(image).astype(np.float64),
          affine[:, [2, 1, 0, 3]], ct, ct_affine)


if __name__ == "__main__":
    try:
        main()
    except AssertionError as error:
        print("read_independently: " + str(error), file=sys.stderr)
        sys.exit(1)
