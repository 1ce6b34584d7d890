#!/bin/bash
# Alternating A/B, three rounds: run in a folder holding posewarp.A / posewarp_bench_pose.A / posewarp_bench_io.A
# (commit fdc9ed4, before the engine's summary in the rig) and posewarp.B / posewarp_bench_pose.B /
# posewarp_bench_io.B (this stop), with the body's rig as built before (README, the command-line section) at
# ${RIG_OLD:-/tmp/body20/body.rig} and the same rig upgraded by B (`posewarp.B rig upgrade RIG_OLD -o RIG`, which adds
# the ENGN section) at ${RIG:-body.rig}, and the repository's bench/poses at ${POSES:-bench/poses}.
# Prints the CLI's `wall:` line with GNU time's wall, CPU and resident peak, the bench's engine creation, and the
# writes of the 20M mannequin's labels and CT; output: ab.txt.
RIG_OLD=${RIG_OLD:-/tmp/body20/body.rig}; RIG=${RIG:-body.rig}; POSES=${POSES:-bench/poses}
[ -f "$RIG" ] || ./posewarp.B -q rig upgrade "$RIG_OLD" -o "$RIG"
rig() { if [ "$1" = A ]; then echo "$RIG_OLD"; else echo "$RIG"; fi; }
for r in 1 2 3; do for v in A B; do for p in body_knee_arm body_arms_moved; do
  rm -f l.nii.gz c.nii.gz
  echo "$r $v cli $p | $(/usr/bin/time -f "%e s wall, %U s user, %S s sys, %M KB" ./posewarp.$v pose "$(rig $v)" \
    --pose $POSES/$p.json --labels-out l.nii.gz --ct-out c.nii.gz 2>&1 | tail -2 | tr '\n' ' ')"
done; done; done
for r in 1 2 3; do for v in A B; do
  out=$(./posewarp_bench_pose.$v --threads 2 --rig "$(rig $v)" --pose $POSES/body_knee_arm.json --quick --repeats 3 2>&1)
  echo "$r $v bench | $(echo "$out" | grep -o 'engine created in [0-9]* ms') | $(echo "$out" | grep -o 'whole pose *[0-9.]* ms')"
done; done
for r in 1 2; do for v in A B; do
  ./posewarp_bench_io.$v --benchmark_filter=MannequinWrite --benchmark_repetitions=3 \
    --benchmark_report_aggregates_only=true 2>&1 | grep -E '_median' | sed "s/^/$r $v io | /"
done; done
