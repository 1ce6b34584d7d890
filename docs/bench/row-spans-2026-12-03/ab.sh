#!/bin/bash
# Alternating A/B of the pose bench, three rounds: run in a folder holding bench.old (posewarp_bench_pose of commit
# c1523f1) and bench.new (of commit 0b3796c, the row spans), with the body's rig (README, the command-line section)
# at /tmp/body20/body.rig. Output: ab.txt beside it.
for r in 1 2 3; do for v in old new; do for p in body_root_moved body_arms_moved body_knee_arm; do
  out=$(./bench.$v --threads 2 --rig /tmp/body20/body.rig --pose ${POSES:-bench/poses}/$p.json --quick --repeats 5 --phases 2>&1)
  echo "$r $v $p | $(echo "$out" | grep -o 'engine created in [0-9]* ms') | $(echo "$out" | grep -o 'whole pose *[0-9.]* ms') | $(echo "$out" | grep -o 'warp-prepare [0-9.]* ms' | head -1) | $(echo "$out" | grep -o 'classify [0-9.]* ms') | $(echo "$out" | grep -o 'warp-labels [0-9.]* ms') | $(echo "$out" | grep -o 'warp-ct [0-9.]* ms')"
done; done; done
