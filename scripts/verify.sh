#!/usr/bin/env bash
# The main job: sets up, then runs the verification campaign (campaigns/paper.toml by default)
# and writes its run document and report under runs/<UTC time>/. Arguments go to `camval verify`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec uv run --frozen camval verify "$@"
