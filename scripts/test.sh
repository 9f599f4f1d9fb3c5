#!/usr/bin/env bash
# The test command: sets up, then runs every test (fast and slow).
# Fails on any failure, and when no test ran.
set -uo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh || exit 1
uv run --frozen pytest -p no:cacheprovider "$@"
status=$?
if [ $status -eq 5 ]; then
    echo "camval tests: no test ran" >&2
    exit 1
fi
exit $status
