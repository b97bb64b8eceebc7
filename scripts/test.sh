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
# two pytest-xdist workers: the DDS graph tests one at a time on one worker (as before: two
# real-time graphs side by side lose frames on this 2-core host), the CPU-only modules on the other;
# test/conftest.py makes the work units; tests marked `exclusive` (the soak) run with nothing beside
# them. MEMO_TEST_WORKERS=0 runs the suite in this one process.
.venv/bin/python -m pytest -q -ra --durations=15 \
  -n "${MEMO_TEST_WORKERS:-2}" --dist loadscope --no-loadscope-reorder "$@"
rc=$?
if [ "$rc" -eq 5 ]; then
  echo "scripts/test.sh: pytest collected no tests (exit 5); nothing failed" >&2
  exit 0
fi
exit "$rc"
