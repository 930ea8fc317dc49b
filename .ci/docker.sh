#!/usr/bin/env bash
# CI (issue 11): get a Docker engine and compose, start dockerd if none runs, build the images
# (compose/build.sh reuses what is already built). Idempotent; prints what it does and timings.
# Exits non-zero with the reason when Docker cannot be had; .ci/run goes on and the compose tests
# then skip, printing why.
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s)
say() { echo "[docker.sh $(date +%H:%M:%S)] $*"; }

need=()
command -v dockerd >/dev/null || need+=(docker.io)
command -v docker-compose >/dev/null || docker compose version >/dev/null 2>&1 || need+=(docker-compose)
command -v debootstrap >/dev/null || need+=(debootstrap)
if (( ${#need[@]} )); then
    if [[ $(id -u) != 0 ]]; then
        say "cannot install ${need[*]}: not root"; exit 1
    fi
    say "apt-get install ${need[*]}"
    apt-get update -q >/dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${need[@]}" >/dev/null
    say "install took $(( $(date +%s) - start )) s"
fi

if ! docker info >/dev/null 2>&1; then
    if [[ $(id -u) != 0 ]]; then
        say "docker daemon not reachable and not root to start one"; exit 1
    fi
    say "starting dockerd (log: /var/log/sqmanip-dockerd.log)"
    nohup dockerd >/var/log/sqmanip-dockerd.log 2>&1 &
    for _ in $(seq 60); do
        docker info >/dev/null 2>&1 && break
        sleep 0.5
    done
    if ! docker info >/dev/null 2>&1; then
        say "dockerd did not come up; last log lines:"; tail -5 /var/log/sqmanip-dockerd.log; exit 1
    fi
fi
say "engine $(docker version -f '{{.Server.Version}}'), compose: $(docker compose version --short 2>/dev/null || docker-compose version --short 2>/dev/null)"

t=$(date +%s)
nice -n 10 compose/build.sh
say "images took $(( $(date +%s) - t )) s; docker.sh took $(( $(date +%s) - start )) s"
