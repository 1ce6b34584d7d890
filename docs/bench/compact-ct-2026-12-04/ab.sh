#!/bin/bash
# Alternating A/B, three rounds: run in a folder holding posewarp.A / posewarp_bench_pose.A (commit ae77df5, the CT
# in float) and posewarp.B / posewarp_bench_pose.B (commit da268b7, the CT in int16 where it fits), with the body's
# rig (`posewarp phantom body -o body --target-voxels 20000000`, then `posewarp rig build --labels body/labels.nii.gz
# --ct body/ct.nii.gz --label-map body/label_map.json -o body.rig`) at ${RIG:-body.rig} and the repository's
# bench/poses at ${POSES:-bench/poses}. Prints the CLI's `wall:` line with GNU time's wall and resident peak, `rig
# info`'s, and the bench's whole pose and warp-ct; then compares the two CLIs' outputs (.nii, uncompressed) byte for
# byte on every pose of bench/poses that the body has the joints of. Output: ab.txt.
RIG=${RIG:-body.rig}; POSES=${POSES:-bench/poses}
for r in 1 2 3; do for v in A B; do
  for p in body_knee_arm body_arms_moved; do
    rm -f l.nii.gz c.nii.gz
    echo "$r $v cli $p | $(/usr/bin/time -f "%e s wall, %M KB" ./posewarp.$v pose "$RIG" \
      --pose $POSES/$p.json --labels-out l.nii.gz --ct-out c.nii.gz 2>&1 | tail -2 | tr '\n' ' ')"
  done
  echo "$r $v rig info | $(/usr/bin/time -f "%e s wall, %M KB" ./posewarp.$v rig info "$RIG" 2>&1 >/dev/null | tail -1)"
  for p in body_knee_arm body_root_moved; do
    out=$(./posewarp_bench_pose.$v --threads 2 --rig "$RIG" --pose $POSES/$p.json --quick --repeats 5 2>&1)
    echo "$r $v bench $p | $(echo "$out" | grep -o 'whole pose *[0-9.]* ms') | $(echo "$out" | grep -o 'warp-ct [0-9.]* ms')"
  done
done; done
for p in $POSES/body_*.json; do
  n=$(basename "$p" .json)
  for v in A B; do ./posewarp.$v pose "$RIG" --pose "$p" --labels-out $v.l.nii --ct-out $v.c.nii >/dev/null 2>&1; done
  if cmp -s A.l.nii B.l.nii && cmp -s A.c.nii B.c.nii; then echo "outputs $n: the same bytes"; else echo "outputs $n: DIFFER"; fi
done
rm -f A.l.nii B.l.nii A.c.nii B.c.nii l.nii.gz c.nii.gz
