#!/usr/bin/env python3
"""Poses the bundled sample through a running posewarp-server and saves the posed labels and CT with nibabel.

    build/server/posewarp-server --listen 127.0.0.1:50051 --store /tmp/store &
    python3 -m venv --system-site-packages ~/posewarp-env && ~/posewarp-env/bin/pip install ./clients/python
    ~/posewarp-env/bin/python clients/python/example.py 127.0.0.1:50051 out/python_labels.nii.gz
"""
import sys

import posewarp

address, out = sys.argv[1], sys.argv[2]
with posewarp.Client(address) as client:
    labels = client.upload("data/totalsegmentator_example/seg_total.nii.gz", kind="labels")
    ct = client.upload("data/totalsegmentator_example/ct.nii.gz", kind="intensity")
    rig = client.build_rig(labels, ct, preset="totalsegmentator", name="sample",
                           progress=lambda stage, fraction: print(f"\r{stage} {100 * fraction:3.0f}%", end=""))
    print(f"\nrig {rig}")
    posed = client.pose(rig, joints={"hip_left": {"flexion": 30}}, method="cor")
    posed.to_nibabel("labels").to_filename(out)
    posed.to_nibabel("ct").to_filename(out.replace("labels", "ct") if "labels" in out else out + ".ct.nii.gz")
    print(f"wrote {out}; soft tissue {100 * posed.report['volume_change']['soft_tissue']:+.1f}%; "
          f"warnings: {posed.report.get('warnings', [])}")
