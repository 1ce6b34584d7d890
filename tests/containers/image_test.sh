#!/usr/bin/env bash
# The image built and run for real: a Debian bookworm base made with debootstrap from the Debian archive (no image
# registry is reachable here) and kept as localhost/posewarp-base:bookworm between runs, docker/Dockerfile built on
# it with `podman build --isolation chroot`, then posewarp-server run from the image with `buildah run --isolation
# chroot` (this sandbox refuses `podman run`'s resource limits) on a free loopback port, the sample posed through it
# with the host's client, and SIGTERM answered by a clean exit. Run by `scripts/test --containers` (not by plain
# scripts/test: the image's build compiles posewarp again, which takes longer than CI allows beside the rest).
# Skipped, with the reason, where podman, buildah or debootstrap is missing. Needs root (debootstrap, chroot).
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT="$PWD"
for tool in podman buildah debootstrap; do
  if ! command -v "$tool" >/dev/null; then
    echo "image test: SKIPPED: $tool is not installed (scripts/test --containers installs the [containers] packages)"
    exit 0
  fi
done
if [[ $(id -u) -ne 0 ]]; then
  echo "image test: SKIPPED: debootstrap and chroot isolation need root"
  exit 0
fi
CLI="$ROOT/build/clients/cli/posewarp"
[[ -x "$CLI" ]] || scripts/build
BASE=localhost/posewarp-base:bookworm
IMAGE=localhost/posewarp:test
WORK="$(mktemp -d /tmp/posewarp-image-test.XXXXXX)"
CONTAINER=""
SERVER_PID=""
cleanup() {
  [[ -n "$SERVER_PID" ]] && kill -9 "$SERVER_PID" 2>/dev/null || true
  [[ -n "$CONTAINER" ]] && buildah rm "$CONTAINER" >/dev/null 2>&1 || true
  rm -rf "$WORK"
}
trap cleanup EXIT
phase_start=$SECONDS
phase() {
  echo "image test: $1 ($((SECONDS - phase_start)) s)"
  phase_start=$SECONDS
}

# 1. The base image, once: debootstrap from the mirror apt uses here.
if ! podman image exists "$BASE"; then
  MIRROR="$(grep -h -m1 -oE 'https?://[^ ]+/debian/?$' /etc/apt/sources.list.d/*.sources /etc/apt/sources.list 2>/dev/null | head -1 || true)"
  MIRROR="${MIRROR:-http://deb.debian.org/debian}"
  debootstrap --variant=minbase bookworm "$WORK/rootfs" "$MIRROR" >"$WORK/debootstrap.log" 2>&1 ||
    { tail -20 "$WORK/debootstrap.log"; echo "image test: debootstrap failed" >&2; exit 1; }
  # The image's apt reads the same archive as the host.
  cp /etc/apt/sources.list.d/debian.sources "$WORK/rootfs/etc/apt/sources.list.d/" 2>/dev/null || true
  [[ -f "$WORK/rootfs/etc/apt/sources.list.d/debian.sources" ]] && rm -f "$WORK/rootfs/etc/apt/sources.list"
  tar -C "$WORK/rootfs" -c . | podman import - "$BASE" >/dev/null
  rm -rf "$WORK/rootfs"
  phase "base image $BASE made with debootstrap from $MIRROR"
else
  phase "base image $BASE cached"
fi

# 2. The image, from docker/Dockerfile with the local base (Docker's format keeps the HEALTHCHECK). With
# POSEWARP_IMAGE_TEST_REUSE=1 an image built by an earlier run is used as it is (the build takes ~20 min here).
if [[ "${POSEWARP_IMAGE_TEST_REUSE:-0}" == 1 ]] && podman image exists "$IMAGE"; then
  phase "image $IMAGE reused (POSEWARP_IMAGE_TEST_REUSE=1)"
else
  podman build --isolation chroot --format docker --build-arg "BASE=$BASE" -f docker/Dockerfile -t "$IMAGE" . \
    >"$WORK/build.log" 2>&1 || { tail -40 "$WORK/build.log"; echo "image test: podman build failed" >&2; exit 1; }
  phase "image $IMAGE built ($(podman image inspect "$IMAGE" --format '{{.Size}}' | awk '{printf "%.0f MB", $1/1e6}'))"
fi

# 3. The server from the image, its store a directory of the test's, on a free loopback port (chroot isolation
# shares the host's network). The entrypoint's user, store and command line, as the image declares them.
PORT="$(/usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')"
CONTAINER="$(buildah from "$IMAGE")"
mkdir -p "$WORK/store"
chown 10001 "$WORK/store"
USER_IN_IMAGE="$(podman image inspect "$IMAGE" --format '{{.Config.User}}')"
[[ "$USER_IN_IMAGE" == posewarp ]] || { echo "image test: the image runs as '$USER_IN_IMAGE', not posewarp" >&2; exit 1; }
buildah run --isolation chroot --user posewarp -v "$WORK/store:/var/lib/posewarp" "$CONTAINER" -- \
  posewarp-server --listen "127.0.0.1:$PORT" --store /var/lib/posewarp >"$WORK/server.out" 2>"$WORK/server.log" &
SERVER_PID=$!
for _ in $(seq 1 100); do
  "$CLI" health --server "127.0.0.1:$PORT" --timeout 1 >/dev/null 2>&1 && break
  kill -0 "$SERVER_PID" 2>/dev/null || { cat "$WORK/server.log"; echo "image test: the server stopped" >&2; exit 1; }
  sleep 0.2
done
"$CLI" health --server "127.0.0.1:$PORT"
# The health check the image declares, run inside it.
buildah run --isolation chroot "$CONTAINER" -- posewarp health --server "127.0.0.1:$PORT" >/dev/null
phase "server from the image serving on 127.0.0.1:$PORT (its HEALTHCHECK command answers)"

# 4. The sample posed through it with the host's client.
SAMPLE="$ROOT/data/totalsegmentator_example"
RIG="$("$CLI" --quiet rig build --server "127.0.0.1:$PORT" --labels "$SAMPLE/seg_total.nii.gz" --ct "$SAMPLE/ct.nii.gz" --name sample)"
[[ "$RIG" =~ ^[0-9a-f]{64}$ ]] || { cat "$WORK/server.log"; echo "image test: no rig id from the build ('$RIG')" >&2; exit 1; }
"$CLI" --quiet pose "$RIG" --server "127.0.0.1:$PORT" --pose "$ROOT/data/poses/sample_hip_flexion.json" \
  --labels-out "$WORK/labels.nii.gz" --ct-out "$WORK/ct.nii.gz" --report "$WORK/report.json"
/usr/bin/python3 - "$WORK" <<'PY'
import json, sys, os
work = sys.argv[1]
report = json.load(open(os.path.join(work, "report.json")))
for name in ("labels.nii.gz", "ct.nii.gz"):
    assert os.path.getsize(os.path.join(work, name)) > 10_000, name + " is too small"
assert "stage_seconds" in report, "the report has no stage timings"
print("image test: posed labels and CT written, report read")
PY
[[ -f "$WORK/store/rigs/$RIG.rig" ]] || { echo "image test: the rig is not in the mounted store" >&2; exit 1; }
phase "sample rigged and posed through the image's server (rig $RIG in the mounted store)"

# 5. SIGTERM to the server (as `docker stop` sends it; buildah itself would kill its child rather than pass the
# signal on, and chroot isolation leaves the server's process visible here): a clean stop.
SERVER_IN_IMAGE=""
for pid in $(pgrep -x posewarp-server || true); do
  tr '\0' ' ' <"/proc/$pid/cmdline" 2>/dev/null | grep -q -- "--listen 127.0.0.1:$PORT " && SERVER_IN_IMAGE=$pid
done
[[ -n "$SERVER_IN_IMAGE" ]] || { echo "image test: the server's process is not found" >&2; exit 1; }
kill -TERM "$SERVER_IN_IMAGE"
set +e
wait "$SERVER_PID"
CODE=$?
set -e
SERVER_PID=""
[[ $CODE -eq 0 ]] || { cat "$WORK/server.log"; echo "image test: the server exited $CODE on SIGTERM" >&2; exit 1; }
grep -q "stopped" "$WORK/server.log" || { cat "$WORK/server.log"; echo "image test: no clean stop in the log" >&2; exit 1; }
phase "SIGTERM: exit 0"
echo "image test: passed"
