#!/bin/bash
# Alternating A/B, three rounds: run in a folder holding posewarp.A / posewarp_bench_pose.A (commit dc495d2, before the
# tables on their rows' spans) and posewarp.B / posewarp_bench_pose.B (this step), with the body's rig (README, the
# command-line section) at ${RIG:-/tmp/body20/body.rig} and the repository's bench/poses at ${POSES:-bench/poses}.
# Prints the CLI's `wall:` line with GNU time's wall and resident peak, then the bench's stages; output: ab.txt.
RIG=${RIG:-/tmp/body20/body.rig}; POSES=${POSES:-bench/poses}
for r in 1 2 3; do for v in A B; do for p in body_knee_arm body_arms_moved; do
  rm -f l.nii.gz c.nii.gz
  echo "$r $v cli $p | $(/usr/bin/time -f "%e s %M KB" ./posewarp.$v pose $RIG --pose $POSES/$p.json \
    --labels-out l.nii.gz --ct-out c.nii.gz 2>&1 | tail -2 | tr '\n' ' ')"
done; done; done
for r in 1 2 3; do for v in A B; do for p in body_root_moved body_arms_moved body_knee_arm; do
  out=$(./posewarp_bench_pose.$v --threads 2 --rig $RIG --pose $POSES/$p.json --quick --repeats 5 --phases 2>&1)
  echo "$r $v bench $p | $(echo "$out" | grep -o 'engine created in [0-9]* ms') | $(echo "$out" | grep -o 'whole pose *[0-9.]* ms') | $(echo "$out" | grep -o 'warp-prepare [0-9.]* ms' | head -1) | $(echo "$out" | grep -o 'classify [0-9.]* ms') | $(echo "$out" | grep -o 'pack [0-9.]* ms') | $(echo "$out" | grep -o 'warp-labels [0-9.]* ms') | $(echo "$out" | grep -o 'warp-ct [0-9.]* ms')"
done; done; done
