#!/usr/bin/env bash
# Build SQManip's container images with no image registry (issue 11). Three stages, each
# skipped when its output is already there, so a re-run only rebuilds what changed:
#   a) base image  sqmanip-base:bookworm  debootstrap --variant=minbase of Debian bookworm (its
#      python3 is 3.11, which takes the host's cp311 wheels) + `docker import`;
#   b) wheelhouse  compose/wheels/        `pip download` of the runtime dependencies of
#      pyproject.toml and clients/python/pyproject.toml, torch pinned to the local CPU build;
#      stamped with a hash of its inputs;
#   c) app image   sqmanip:latest         `docker build` of compose/Dockerfile (multi-stage: the
#      wheelhouse is only in the builder stage, never in a layer of the final image).
# Usage: compose/build.sh [--force-base] [--force-wheels] [--no-cache]
# Environment: SQMANIP_BASE_IMAGE, SQMANIP_IMAGE, DEBIAN_MIRROR, PYTHON (host python3.11 with pip).
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
BASE_IMAGE=${SQMANIP_BASE_IMAGE:-sqmanip-base:bookworm}
APP_IMAGE=${SQMANIP_IMAGE:-sqmanip:latest}
SUITE=bookworm
MIRROR=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
WHEELS=$ROOT/compose/wheels
# Runtime packages of the base image. python3-venv brings ensurepip (pip in the venv);
# ca-certificates for anything TLS; libgomp1 is bundled by torch but also used by scikit-learn
# wheels' OpenMP fallback; passwd for `useradd`. pybullet runs DIRECT (no GL, no X) and needs no
# libgl1 (checked by the smoke test at the end).
BASE_PACKAGES=python3,python3-venv,ca-certificates,libgomp1,passwd
TORCH_REQ="torch==2.13.0+cpu"
FORCE_BASE=0 FORCE_WHEELS=0 NO_CACHE=()
for arg in "$@"; do
    case $arg in
        --force-base) FORCE_BASE=1 ;;
        --force-wheels) FORCE_WHEELS=1 ;;
        --no-cache) NO_CACHE=(--no-cache) ;;
        -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
        *) echo "build.sh: unknown argument $arg" >&2; exit 2 ;;
    esac
done

if [[ -z ${PYTHON:-} ]]; then
    if [[ -x $ROOT/.venv/bin/python ]]; then PYTHON=$ROOT/.venv/bin/python; else PYTHON=python3; fi
fi

log() { echo "[build $(date +%H:%M:%S)] $*"; }
T0=$(date +%s)
stage_start() { STAGE_T=$(date +%s); log "$1"; }
stage_end() { log "$1 took $(( $(date +%s) - STAGE_T )) s"; }

command -v docker >/dev/null || { echo "build.sh: docker not found (run .ci/docker.sh)" >&2; exit 1; }
docker info >/dev/null 2>&1 || { echo "build.sh: docker daemon not reachable" >&2; exit 1; }

# --- a) base image ---------------------------------------------------------------------------
stage_start "a) base image $BASE_IMAGE"
if [[ $FORCE_BASE == 0 ]] && docker image inspect "$BASE_IMAGE" >/dev/null 2>&1; then
    log "a) $BASE_IMAGE exists, reused"
else
    if ! command -v debootstrap >/dev/null; then
        log "a) installing debootstrap"
        apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q debootstrap
    fi
    ROOTFS=$(mktemp -d /var/tmp/sqmanip-rootfs.XXXXXX)
    trap 'rm -rf "$ROOTFS"' EXIT
    log "a) debootstrap --variant=minbase --include=$BASE_PACKAGES $SUITE $ROOTFS $MIRROR"
    debootstrap --variant=minbase --include="$BASE_PACKAGES" "$SUITE" "$ROOTFS" "$MIRROR" \
        > "$ROOTFS.log" 2>&1 || { tail -30 "$ROOTFS.log" >&2; exit 1; }
    rm -f "$ROOTFS.log"
    rm -rf "$ROOTFS"/var/cache/apt/archives/*.deb "$ROOTFS"/var/lib/apt/lists/* \
        "$ROOTFS"/usr/share/doc/* "$ROOTFS"/usr/share/man/* "$ROOTFS"/usr/share/locale/*
    tar -C "$ROOTFS" -c . | docker import \
        --change 'ENV LANG=C.UTF-8' \
        --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
        --change 'CMD ["/bin/bash"]' \
        --message "debootstrap --variant=minbase $SUITE ($BASE_PACKAGES)" - "$BASE_IMAGE" >/dev/null
    rm -rf "$ROOTFS"
    trap - EXIT
fi
stage_end "a) base image"

# --- b) wheelhouse ---------------------------------------------------------------------------
stage_start "b) wheelhouse $WHEELS"
REQS=$("$PYTHON" - "$ROOT" "$TORCH_REQ" <<'EOF'
import sys, tomllib, pathlib
root, torch_req = pathlib.Path(sys.argv[1]), sys.argv[2]
reqs = []
for p in (root / "pyproject.toml", root / "clients/python/pyproject.toml"):
    reqs += tomllib.loads(p.read_text())["project"]["dependencies"]
# torch: the CPU build on this machine's disk (find-links /opt/wheels), never a CUDA build.
reqs = [torch_req if r.replace(" ", "").startswith("torch==") else r for r in reqs]
# build backend of the two projects (installed from source in the builder stage, offline)
reqs += ["setuptools>=68", "wheel"]
print("\n".join(sorted(set(reqs))))
EOF
)
STAMP_HASH=$(printf '%s\n%s\n' "$REQS" "$("$PYTHON" -c 'import sys; print(sys.version)')" | sha256sum | cut -c1-16)
if [[ $FORCE_WHEELS == 0 && -f $WHEELS/.stamp && $(cat "$WHEELS/.stamp") == "$STAMP_HASH" ]]; then
    log "b) wheelhouse up to date ($STAMP_HASH), reused"
else
    mkdir -p "$WHEELS"
    rm -f "$WHEELS"/.stamp "$WHEELS"/*.whl "$WHEELS"/*.tar.gz "$WHEELS"/*.zip
    printf '%s\n' "$REQS" > "$WHEELS/requirements.txt"
    log "b) pip download $(echo "$REQS" | wc -l) requirements (binary only, cp311)"
    # (the host's pip config lists local indexes that lack most projects: drop those warnings)
    "$PYTHON" -m pip download -q --only-binary=:all: -d "$WHEELS" -r "$WHEELS/requirements.txt" \
        2> >(grep -v 'is ignored: it is neither a file nor a directory' >&2)
    if ls "$WHEELS" | grep -qiE '^nvidia|^triton'; then
        echo "build.sh: CUDA wheels landed in the wheelhouse: $(ls "$WHEELS" | grep -iE '^nvidia|^triton')" >&2
        exit 1
    fi
    ls "$WHEELS" | grep -q '^torch-2\.13\.0+cpu-' || {
        echo "build.sh: the torch wheel is not the CPU build: $(ls "$WHEELS" | grep '^torch-')" >&2; exit 1; }
    echo "$STAMP_HASH" > "$WHEELS/.stamp"
fi
log "b) $(ls "$WHEELS"/*.whl | wc -l) wheels, $(du -sh "$WHEELS" | cut -f1); torch: $(ls "$WHEELS" | grep '^torch-')"
stage_end "b) wheelhouse"

# --- c) app image ----------------------------------------------------------------------------
stage_start "c) app image $APP_IMAGE"
# The legacy builder (Debian's engine, no buildx) caches layers by content, so an unchanged tree
# rebuilds in seconds. The build context is filtered by .dockerignore.
BUILD_LOG=$(mktemp /tmp/sqmanip-docker-build.XXXXXX.log)
OLD_ID=$(docker image inspect -f '{{.Id}}' "$APP_IMAGE" 2>/dev/null || true)
DOCKER_BUILDKIT=0 docker build "${NO_CACHE[@]}" --build-arg "BASE_IMAGE=$BASE_IMAGE" \
    -f "$ROOT/compose/Dockerfile" -t "$APP_IMAGE" "$ROOT" > "$BUILD_LOG" 2>&1 \
    || { tail -40 "$BUILD_LOG" >&2; echo "build.sh: docker build failed (log: $BUILD_LOG)" >&2; exit 1; }
log "c) docker build: $(grep -c 'Using cache' "$BUILD_LOG") cached steps, $(grep -c '^Step ' "$BUILD_LOG") steps (log: $BUILD_LOG)"
NEW_ID=$(docker image inspect -f '{{.Id}}' "$APP_IMAGE")
if [[ -n $OLD_ID && $OLD_ID != "$NEW_ID" ]]; then  # the replaced image (~2 GB), if nothing uses it
    docker rmi "$OLD_ID" >/dev/null 2>&1 && log "c) removed the previous $APP_IMAGE ($OLD_ID)" || true
fi
log "c) smoke test: imports and a PyBullet DIRECT client inside $APP_IMAGE"
docker run --rm -i --network none "$APP_IMAGE" python - <<'EOF'
import pybullet as p, pybullet_data, torch
import fcl, grpc, pinocchio, zenoh  # noqa: F401  (native wheels load)
import sqmanip.gateway, sqmanip.sim.server, sqmanip_client  # noqa: F401
c = p.connect(p.DIRECT)
p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=c)
p.loadURDF("franka_panda/panda.urdf", useFixedBase=True, physicsClientId=c)
w, h, *_ = p.getCameraImage(32, 24, physicsClientId=c)
if torch.version.cuda is not None:
    raise SystemExit(f"CUDA torch in the image: {torch.version.cuda}")
print("smoke ok: torch", torch.__version__, "| pinocchio", pinocchio.__version__, "| camera", w, h)
EOF
stage_end "c) app image"
log "$APP_IMAGE: $(docker image inspect -f '{{.Size}}' "$APP_IMAGE" | awk '{printf "%.0f MB", $1/1e6}'), total $(( $(date +%s) - T0 )) s"
