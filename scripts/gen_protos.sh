#!/usr/bin/env bash
# Regenerate services/sqmanip/v1 from protos/ (see protos/README.md). Pass --check to verify only.
set -euo pipefail
cd "$(dirname "$0")/.."
exec python -m sqmanip.rpc.gen "$@"
