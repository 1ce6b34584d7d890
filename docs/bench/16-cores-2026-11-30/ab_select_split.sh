#!/bin/bash
# The select/split step (011a513) against 6927e5a's bench on the same machine, then the new sweep. Packed here with
#   ../shared/tools/device_bundle.sh .bundle/bench2.tar.xz build/bench/posewarp_bench_pose build/clients/cli/posewarp \
#     OLD/posewarp_bench_pose_old   (6927e5a's bench, renamed); run there from the repository root with .bundle carried.
set -u
REPO=$PWD
out="${OUT:-/tmp/out2}"; mkdir -p "$out"
u=$(mktemp -d); tar xJf .bundle/bench2.tar.xz -C "$u" || exit 1
export LD_LIBRARY_PATH="$u/lib"; B="$u/bin"
w=$(mktemp -d); cd "$w"
echo '{"format": "posewarp.pose", "version": 1, "joints": {"knee_left": {"angles_deg": {"flexion": 90}}, "shoulder_right": {"angles_deg": {"abduction": 90}}}}' > knee_arm.json
"$B/posewarp" -q phantom body -o body20 --target-voxels 20000000 > /dev/null && \
  "$B/posewarp" -q rig build --labels body20/labels.nii.gz --ct body20/ct.nii.gz --label-map body20/label_map.json -o body20/body.rig > /dev/null
ls -la body20/body.rig | tee "$out/ab.txt"
for round in 1 2; do
  for pose in knee_arm.json "$REPO/bench/poses/body_root_moved.json" "$REPO/bench/poses/body_arms_moved.json"; do
    for t in 16 2; do
      for v in old new; do
        bench="$B/posewarp_bench_pose"; [ $v = old ] && bench="$B/posewarp_bench_pose_old"
        echo "round $round $v $(basename $pose) threads $t: $(timeout 60 "$bench" --rig body20/body.rig --pose "$pose" --quick --repeats 9 --threads $t 2>&1 | grep -o 'whole pose.*')"
      done
    done
  done
done 2>&1 | tee -a "$out/ab.txt"
timeout 200 "$B/posewarp_bench_pose" --threads 2,4,8,16 --repeats 3 --mannequin-mvoxels 0 \
  --data-dir "$REPO/data/totalsegmentator_example" 2>&1 | tee "$out/pose_sweep.txt" | grep -v '^ \|^{\|^}\|^\]'
