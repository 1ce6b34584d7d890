#!/usr/bin/env bash
# Writes the seed corpus of fuzz_dicom (tests/fuzz/corpus/dicom) with posewarp itself: a small made-up study (8 x 6 x
# 4 voxels of 1 mm at the origin, axes along LPS: the grid fuzz_dicom reads SEGs onto) exported as DICOM in both
# format pairs; each seed is the byte that picks the reader (0: CT, 1: SEG) followed by one Part 10 file.
# Usage: tests/fuzz/make_dicom_seeds.sh [POSEWARP (build/clients/cli/posewarp)]
set -euo pipefail
cd "$(dirname "$0")/../.."
posewarp="${1:-build/clients/cli/posewarp}"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
/usr/bin/python3 - "$work" <<'PY'
import sys
import nibabel as nib
import numpy as np
x, y, z = np.indices((8, 6, 4))
ct = (-1000 + 40 * x + 100 * y + 7 * z).astype(np.int16)
labels = ((x >= 2) & (x < 6)).astype(np.uint8) + 2 * ((y >= 3) & (z >= 1)).astype(np.uint8)
affine = np.diag([-1.0, -1.0, 1.0, 1.0])  # NIfTI is RAS: this is the identity in DICOM's LPS
nib.save(nib.Nifti1Image(ct, affine), sys.argv[1] + "/ct.nii.gz")
nib.save(nib.Nifti1Image(labels, affine), sys.argv[1] + "/labels.nii.gz")
PY
corpus=tests/fuzz/corpus/dicom
mkdir -p "$corpus"
for formats in "series binary" "enhanced labelmap"; do
  read -r ct seg <<<"$formats"
  "$posewarp" -q dicom export --ct "$work/ct.nii.gz" --labels "$work/labels.nii.gz" --patient-id FUZZ \
    --uid-root 1.2.826.0.1.3680043.10.43 --ct-format "$ct" --seg-format "$seg" -o "$work/$ct"
  { printf '\x00'; cat "$(ls "$work/$ct/ct/"*.dcm | head -1)"; } >"$corpus/ct-$ct"
  { printf '\x01'; cat "$work/$ct/seg.dcm"; } >"$corpus/seg-$seg"
done
ls -l "$corpus"
