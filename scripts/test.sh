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
# two pytest-xdist workers: most of the suite waits on real-time DDS graphs, so two at a time
# roughly halve its wall time. Whole files per worker (module fixtures are built once), the longest
# first (test/conftest.py); tests marked `exclusive` (the soak) run with no other test beside them.
# MEMO_TEST_WORKERS=0 runs it in this one process, as before.
.venv/bin/python -m pytest -q -ra --durations=15 \
  -n "${MEMO_TEST_WORKERS:-2}" --dist loadfile --no-loadscope-reorder "$@"
rc=$?
if [ "$rc" -eq 5 ]; then
  echo "scripts/test.sh: pytest collected no tests (exit 5); nothing failed" >&2
  exit 0
fi
exit "$rc"
