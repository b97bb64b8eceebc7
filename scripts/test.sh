#!/usr/bin/env bash
# Run the whole test suite (sets up .venv first). Extra arguments go to pytest.
set -uo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh || exit 1
# DDS tests stay on this host; each test picks its own ROS_DOMAIN_ID (test/conftest.py)
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export MPLBACKEND=Agg
# numpy's BLAS on one thread, as in the nodes (memo_ros/nodes/__init__.py): on a shared 2-core
# machine a second spinning BLAS thread made the EKF's small products many times slower
export OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1} OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
# Two pytest-xdist workers: the DDS graph tests one at a time on one worker, the CPU-only modules
# on the other, tests marked `exclusive` (the soak) with nothing beside them (test/conftest.py
# makes the work units). MEMO_TEST_WORKERS=0 runs the suite serially in this one process.
workers=${MEMO_TEST_WORKERS:-2}
dist=()
[ "$workers" != 0 ] && dist=(-n "$workers" --dist loadscope --no-loadscope-reorder)
.venv/bin/python -m pytest -q -ra --durations=15 "${dist[@]}" "$@"
rc=$?
if [ "$rc" -eq 5 ]; then
  echo "scripts/test.sh: pytest collected no tests (exit 5); nothing failed" >&2
  exit 0
fi
exit "$rc"
