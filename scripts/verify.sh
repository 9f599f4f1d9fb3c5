#!/usr/bin/env bash
# The main job: sets up, then runs the verification campaign and writes its report.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec uv run --frozen camval catalogue list "$@"
