#!/usr/bin/python3
"""Poses the bundled sample through a running posewarp-server and saves the posed labels with nibabel.

    build/server/posewarp-server --store /tmp/store &            # prints its address
    PYTHONPATH=build/clients/python/generated:clients/python \\
        clients/python/example.py 127.0.0.1:50051 out/python_labels.nii.gz
"""
import sys

import nibabel

from posewarp_client import Client

address, out = sys.argv[1], sys.argv[2]
with Client(address) as client:
    labels = client.upload("data/totalsegmentator_example/seg_total.nii.gz", kind="labels")
    ct = client.upload("data/totalsegmentator_example/ct.nii.gz", kind="intensity")
    rig = client.build_rig(labels, ct, preset="totalsegmentator", name="sample",
                           progress=lambda stage, fraction: print(f"\r{stage} {100 * fraction:3.0f}%", end=""))
    print(f"\nrig {rig}")
    posed = client.pose(rig, "data/poses/sample_hip_flexion.json", method="cor")
    nibabel.save(nibabel.Nifti1Image(posed.labels, posed.affine), out)
    print(f"wrote {out}; warnings: {posed.report.get('warnings', [])}")
